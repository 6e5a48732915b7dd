"""A tiny LeRobot EVO1 built fully offline (LeRobot >= 0.6.1): a random InternVL3 (a one-layer vision tower at 28
pixels, two Qwen2 layers of 32, a word-level tokenizer with InternVL's image tokens) written to a local folder with
its weights, which EVO1's embedder loads, and LeRobot's Evo1Policy over it."""

from __future__ import annotations

from pathlib import Path

import torch

from tests.lerobot_tiny import randomise_target_time

#: EVO1 pads state and action to these widths; the tiny policy's own are narrower, so the padding is exercised
MAX_STATE_DIM, MAX_ACTION_DIM, STATE_DIM, ACTION_DIM, HORIZON = 8, 8, 6, 4, 4
IMAGE_KEY, EVO1_IMAGE_SIZE = "observation.images.top", 28
TASKS = ["pick the red cube", "open the drawer", "push the blue cube", "place a cube"]


def write_tiny_internvl3(directory: Path) -> Path:
    """The tiny InternVL3 folder (config, random weights, tokenizer) in ``directory``."""
    from snapflow.adapters.lerobot.evo1_checkpoint import SIZES, write_random_internvl3

    assert SIZES["tiny"].vision["image_size"] == EVO1_IMAGE_SIZE  # the size the helpers below build for
    return write_random_internvl3(directory, "tiny")


def build_tiny_evo1(vlm: Path, state_dim: int = STATE_DIM, image_key: str = IMAGE_KEY, **options):
    """LeRobot's Evo1Policy (about 70k parameters) over the tiny InternVL3 folder ``vlm``, in float32 on the CPU, for a
    ``state_dim``-D state, one 32-pixel camera (EVO1 resizes it to 28) and 4-D actions; ``options`` are more
    Evo1Config fields."""
    from lerobot.configs.types import FeatureType, PolicyFeature
    from lerobot.policies.evo1.configuration_evo1 import Evo1Config
    from lerobot.policies.evo1.modeling_evo1 import Evo1Policy

    sizes = dict(embed_dim=32, hidden_dim=32, state_hidden_dim=32, num_heads=2, num_layers=2)
    config = Evo1Config(
        vlm_model_name=str(vlm),
        vlm_num_layers=2,
        vlm_dtype="float32",
        image_resolution=(EVO1_IMAGE_SIZE, EVO1_IMAGE_SIZE),
        max_text_length=64,
        max_views=2,
        use_flash_attn=False,
        chunk_size=HORIZON,
        n_action_steps=HORIZON,
        max_state_dim=MAX_STATE_DIM,
        max_action_dim=MAX_ACTION_DIM,
        device="cpu",
        push_to_hub=False,
        input_features={
            "observation.state": PolicyFeature(type=FeatureType.STATE, shape=(state_dim,)),
            image_key: PolicyFeature(type=FeatureType.VISUAL, shape=(3, 32, 32)),
        },
        output_features={"action": PolicyFeature(type=FeatureType.ACTION, shape=(ACTION_DIM,))},
        **{**sizes, **options},
    )
    with torch.random.fork_rng(devices=[]):  # the action head's init, the same every build
        torch.manual_seed(0)
        return Evo1Policy(config)


def tiny_evo1_processors(policy, state_dim: int = STATE_DIM) -> tuple:
    """EVO1's pre- and post-processors for ``policy`` with [-1, 1] min-max statistics."""
    from lerobot.policies.evo1.processor_evo1 import make_evo1_pre_post_processors

    stats = {
        key: {"min": torch.full((dim,), -1.0), "max": torch.ones(dim)}
        for key, dim in (("observation.state", state_dim), ("action", ACTION_DIM))
    }
    return make_evo1_pre_post_processors(policy.config, dataset_stats=stats)


def raw_evo1_batch(batch_size: int = 4, seed: int = 0, state_dim: int = STATE_DIM) -> dict:
    """A raw LeRobot batch for the tiny EVO1's pre-processor: state, one camera in [0, 1], tasks and action chunks."""
    generator = torch.Generator().manual_seed(seed)
    return {
        "observation.state": torch.rand(batch_size, state_dim, generator=generator) * 2 - 1,
        IMAGE_KEY: torch.rand(batch_size, 3, 32, 32, generator=generator),
        "task": [TASKS[row % len(TASKS)] for row in range(batch_size)],
        "action": torch.rand(batch_size, HORIZON, ACTION_DIM, generator=generator) * 2 - 1,
    }


def evo1_rows(batch: dict, rows: slice) -> dict:
    """The rows ``rows`` of a pre-processed EVO1 batch, its tasks (a list) included."""
    return {key: value[rows] if isinstance(value, (torch.Tensor, list)) else value for key, value in batch.items()}


def save_tiny_evo1_student(vlm: Path, directory: Path, state_dim: int = STATE_DIM) -> Path:
    """A distilled tiny EVO1 (phi_s non-zero) saved by snapflow with its processors (min-max statistics)."""
    from snapflow.adapters.lerobot import save_distilled, wrap_policy

    policy = build_tiny_evo1(vlm, state_dim=state_dim)
    save_distilled(randomise_target_time(wrap_policy(policy)), directory)
    for processor in tiny_evo1_processors(policy, state_dim):
        processor.save_pretrained(directory)
    return directory


__all__ = [
    "build_tiny_evo1",
    "evo1_rows",
    "raw_evo1_batch",
    "save_tiny_evo1_student",
    "tiny_evo1_processors",
    "write_tiny_internvl3",
]
