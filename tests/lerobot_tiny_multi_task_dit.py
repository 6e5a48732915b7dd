"""A tiny LeRobot multi-task DiT built fully offline (LeRobot >= 0.5), trained by flow matching: a one-layer CLIP
written to a local folder (its name holds "clip", as the config asks) for both encoders, with the tiny SmolVLM's
word-level tokenizer beside it for its processors."""

from __future__ import annotations

import shutil
from pathlib import Path

import torch

from tests.lerobot_tiny import IMAGE_SIZE, randomise_target_time

CLIP_IMAGE_SIZE, CLIP_VOCABULARY = 32, 64


def write_tiny_clip(directory: Path, tokenizer: Path | None = None) -> Path:
    """A random one-layer CLIP (vision and text) at ``directory`` (a name holding "clip"), and the tokenizer files of
    the folder ``tokenizer`` beside it."""
    from transformers import CLIPConfig, CLIPModel

    if not (directory / "config.json").is_file():
        blocks = dict(hidden_size=16, intermediate_size=32, num_hidden_layers=1, num_attention_heads=2)
        config = CLIPConfig(
            text_config=dict(**blocks, vocab_size=CLIP_VOCABULARY, max_position_embeddings=16),
            vision_config=dict(**blocks, image_size=CLIP_IMAGE_SIZE, patch_size=16),
            projection_dim=16,
        )
        torch.manual_seed(0)
        CLIPModel(config).save_pretrained(directory)
    for source in tokenizer.iterdir() if tokenizer else ():
        if source.name.startswith(("tokenizer", "special_tokens")):
            shutil.copyfile(source, directory / source.name)
    return directory


def build_tiny_multi_task_dit(
    clip_directory: Path,
    seed: int = 0,
    state_dim: int = 6,
    image_key: str = "observation.images.top",
    image_size: int = IMAGE_SIZE,
):
    """A random LeRobot MultiTaskDiTPolicy by flow matching (one observation step, 4-action chunks of 4-D actions,
    10 integration steps), its encoders the tiny CLIP at ``clip_directory``; dropout off, as the tests compare passes
    made in training mode exactly."""
    from lerobot.configs.types import FeatureType, PolicyFeature
    from lerobot.policies.multi_task_dit.configuration_multi_task_dit import MultiTaskDiTConfig
    from lerobot.policies.multi_task_dit.modeling_multi_task_dit import MultiTaskDiTPolicy

    torch.manual_seed(seed)
    config = MultiTaskDiTConfig(
        objective="flow_matching",
        vision_encoder_name=str(clip_directory),
        text_encoder_name=str(clip_directory),
        n_obs_steps=1,
        horizon=4,
        n_action_steps=4,
        hidden_dim=32,
        num_layers=2,
        num_heads=2,
        dropout=0.0,
        timestep_embed_dim=16,
        image_crop_shape=(CLIP_IMAGE_SIZE, CLIP_IMAGE_SIZE),
        tokenizer_max_length=16,
        num_integration_steps=10,
        device="cpu",
        push_to_hub=False,
        input_features={
            "observation.state": PolicyFeature(type=FeatureType.STATE, shape=(state_dim,)),
            image_key: PolicyFeature(type=FeatureType.VISUAL, shape=(3, image_size, image_size)),
        },
        output_features={"action": PolicyFeature(type=FeatureType.ACTION, shape=(4,))},
    )
    policy = MultiTaskDiTPolicy(config)
    with torch.no_grad():  # AdaLN-Zero starts its modulation at zero (time and observation ignored): stand in for a
        for block in policy.noise_predictor.transformer_blocks:  # trained checkpoint
            block.adaLN_modulation[-1].weight.normal_(0, 0.3)
    return policy


def save_tiny_multi_task_dit_student(clip_directory: Path, directory: Path, state_dim: int = 6) -> Path:
    """A distilled tiny multi-task DiT (phi_s non-zero) saved by snapflow with processors of unit statistics."""
    from lerobot.policies.factory import make_pre_post_processors

    from snapflow.adapters.lerobot import save_distilled, wrap_policy

    policy = build_tiny_multi_task_dit(clip_directory, state_dim=state_dim)
    save_distilled(randomise_target_time(wrap_policy(policy)), directory)
    for processor in make_pre_post_processors(policy.config, dataset_stats=unit_statistics(state_dim)):
        processor.save_pretrained(directory)
    return directory


def unit_statistics(state_dim: int = 6) -> dict[str, dict[str, torch.Tensor]]:
    """Normalisation statistics that change nothing, for the tiny policy's state, action and camera."""
    unit = {"mean": 0.0, "std": 1.0, "min": -1.0, "max": 1.0}
    shapes = {"observation.state": (state_dim,), "action": (4,), "observation.images.top": (3, 1, 1)}
    return {key: {name: torch.full(shape, value) for name, value in unit.items()} for key, shape in shapes.items()}


__all__ = ["build_tiny_multi_task_dit", "save_tiny_multi_task_dit_student", "unit_statistics", "write_tiny_clip"]
