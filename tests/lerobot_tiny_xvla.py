"""A tiny LeRobot X-VLA built fully offline (LeRobot >= 0.5): Florence-2 shrunk through X-VLA's own
``florence_config``, and, for its processors, the tiny SmolVLM's word-level tokenizer."""

from __future__ import annotations

from pathlib import Path

import torch

from tests.lerobot_tiny import IMAGE_SIZE, TINY_POLICY_SIZES, randomise_target_time

XVLA_VOCABULARY = 64  # above every id of the tiny word list


def build_tiny_xvla(
    seed: int = 0,
    state_dim: int = 6,
    image_key: str = "observation.images.top",
    image_size: int = IMAGE_SIZE,
    tokenizer: str | None = None,
    action_dim: int = 4,
):
    """A random LeRobot XVLAPolicy at tiny size (about 160k parameters): a two-stage-wide DaViT and a one-layer
    BART encoder as its Florence-2, a two-block soft-prompted transformer, X-VLA's ``auto`` action space (an
    ``action_dim`` below ``max_action_dim``, 4, pads its chunks); ``tokenizer`` names a local tokenizer folder for its
    processors (X-VLA's default is a hub id)."""
    from lerobot.configs.types import FeatureType, PolicyFeature
    from lerobot.policies.xvla.configuration_xvla import XVLAConfig
    from lerobot.policies.xvla.modeling_xvla import XVLAPolicy

    florence = {
        "vision_config": dict(
            depths=[1, 1, 1, 1],
            embed_dim=[16, 32, 32, 32],
            num_heads=[1, 2, 2, 2],
            num_groups=[1, 2, 2, 2],
            window_size=2,
            projection_dim=32,
            max_position_embeddings=16,
            max_temporal_embeddings=4,
            drop_path_rate=0.0,
        ),
        "text_config": dict(
            d_model=32,
            encoder_layers=1,
            decoder_layers=1,
            encoder_attention_heads=2,
            decoder_attention_heads=2,
            encoder_ffn_dim=64,
            decoder_ffn_dim=64,
            vocab_size=XVLA_VOCABULARY,
            max_position_embeddings=64,
            dropout=0.0,
        ),
    }
    sizes = {**TINY_POLICY_SIZES, **({"tokenizer_name": tokenizer} if tokenizer else {})}
    sizes["max_action_dim"] = max(sizes["max_action_dim"], action_dim)  # auto's width holds the dataset's
    torch.manual_seed(seed)
    config = XVLAConfig(
        florence_config=florence,
        hidden_size=32,
        depth=2,
        num_heads=2,
        num_domains=2,
        len_soft_prompts=4,
        max_len_seq=64,
        action_mode="auto",
        **sizes,
        input_features={
            "observation.state": PolicyFeature(type=FeatureType.STATE, shape=(state_dim,)),
            image_key: PolicyFeature(type=FeatureType.VISUAL, shape=(3, image_size, image_size)),
        },
        output_features={"action": PolicyFeature(type=FeatureType.ACTION, shape=(action_dim,))},
    )
    return without_dropout(XVLAPolicy(config))


def without_dropout(policy):
    """``policy`` with every dropout off: X-VLA's blocks fix theirs at 0.1, and the tests compare passes made in
    training mode exactly."""
    for module in policy.modules():
        if isinstance(module, torch.nn.Dropout):
            module.p = 0.0
    return policy


def save_tiny_xvla_student(
    vlm_directory: Path,
    directory: Path,
    state_dim: int = 6,
    image_key: str = "observation.images.top",
    image_size: int = IMAGE_SIZE,
    action_dim: int = 4,
) -> Path:
    """A distilled tiny X-VLA (phi_s non-zero; by default a 6-D state, one ``observation.images.top`` and 4-D
    actions) saved by snapflow with its processors, which tokenize with the tiny SmolVLM's word-level tokenizer (ids
    under :data:`XVLA_VOCABULARY`)."""
    from lerobot.policies.factory import make_pre_post_processors

    from snapflow.adapters.lerobot import save_distilled, wrap_policy

    policy = build_tiny_xvla(
        state_dim=state_dim,
        image_key=image_key,
        image_size=image_size,
        tokenizer=str(vlm_directory),
        action_dim=action_dim,
    )
    save_distilled(randomise_target_time(wrap_policy(policy)), directory)
    for processor in make_pre_post_processors(policy.config, dataset_stats=None):
        processor.save_pretrained(directory)
    return directory


__all__ = ["XVLA_VOCABULARY", "build_tiny_xvla", "save_tiny_xvla_student", "without_dropout"]
