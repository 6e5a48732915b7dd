"""A tiny LeRobot GR00T N1.7 built fully offline (LeRobot >= 0.6): a random two-layer Qwen3-VL (config, word-level
tokenizer with a chat template, image and video processors; no weights) and a random GR00T N1.7 checkpoint over it,
both written to local folders; LeRobot's GrootPolicy loads the checkpoint by its ``base_model_path``."""

from __future__ import annotations

from pathlib import Path

import torch

from tests.lerobot_tiny import randomise_target_time

#: GR00T pads state and action to these widths; the tiny policy's own are narrower, so the padding is exercised
MAX_STATE_DIM, MAX_ACTION_DIM, STATE_DIM, ACTION_DIM, HORIZON = 8, 8, 6, 4, 4
IMAGE_KEY, GROOT_IMAGE_SIZE = "observation.images.top", 32


def write_tiny_groot(directory: Path) -> Path:
    """The tiny Qwen3-VL folder and the GR00T checkpoint over it, inside ``directory``; the checkpoint's folder."""
    from snapflow.adapters.lerobot.groot_checkpoint import SIZES, write_random_groot

    tiny = SIZES["tiny"]  # the sizes the helpers below build for
    widths = tiny.groot["max_state_dim"], tiny.groot["max_action_dim"], tiny.groot["action_horizon"], tiny.image_size
    assert widths == (MAX_STATE_DIM, MAX_ACTION_DIM, HORIZON, GROOT_IMAGE_SIZE)
    return write_random_groot(directory, "tiny")


def build_tiny_groot(checkpoint: Path, state_dim: int = STATE_DIM, image_key: str = IMAGE_KEY, **options):
    """LeRobot's GrootPolicy (127k parameters) from the tiny checkpoint folder ``checkpoint``, in float32 on the CPU,
    for a ``state_dim``-D state, one camera and 4-D actions; ``options`` are more GrootConfig fields."""
    from lerobot.configs.types import FeatureType, PolicyFeature
    from lerobot.policies.groot.configuration_groot import GrootConfig
    from lerobot.policies.groot.modeling_groot import GrootPolicy

    config = GrootConfig(
        base_model_path=str(checkpoint),
        max_state_dim=MAX_STATE_DIM,
        max_action_dim=MAX_ACTION_DIM,
        chunk_size=HORIZON,
        n_action_steps=HORIZON,
        use_bf16=False,
        device="cpu",
        push_to_hub=False,
        input_features={
            "observation.state": PolicyFeature(type=FeatureType.STATE, shape=(state_dim,)),
            image_key: PolicyFeature(type=FeatureType.VISUAL, shape=(3, GROOT_IMAGE_SIZE, GROOT_IMAGE_SIZE)),
        },
        output_features={"action": PolicyFeature(type=FeatureType.ACTION, shape=(ACTION_DIM,))},
        **options,
    )
    return GrootPolicy(config)


def tiny_groot_processors(policy, state_dim: int = STATE_DIM) -> tuple:
    """GR00T's pre- and post-processors for ``policy`` with [-1, 1] min-max statistics, their Qwen3-VL step reading
    the checkpoint's local Qwen3-VL folder."""
    from snapflow.adapters.lerobot.groot import groot_processors

    stats = {
        key: {"min": torch.full((dim,), -1.0), "max": torch.ones(dim)}
        for key, dim in (("observation.state", state_dim), ("action", ACTION_DIM))
    }
    return groot_processors(policy, stats)


def raw_groot_batch(batch_size: int = 4, seed: int = 0, state_dim: int = STATE_DIM) -> dict:
    """A raw LeRobot batch for the tiny GR00T's pre-processor: state, one camera in [0, 1], tasks and action chunks."""
    generator = torch.Generator().manual_seed(seed)
    tasks = ["pick the red cube", "open the drawer", "push the blue cube", "place a cube"]
    return {
        "observation.state": torch.rand(batch_size, state_dim, generator=generator) * 2 - 1,
        IMAGE_KEY: torch.rand(batch_size, 3, GROOT_IMAGE_SIZE, GROOT_IMAGE_SIZE, generator=generator),
        "task": [tasks[row % len(tasks)] for row in range(batch_size)],
        "action": torch.rand(batch_size, HORIZON, ACTION_DIM, generator=generator) * 2 - 1,
    }


def groot_rows(batch: dict, rows: slice) -> dict:
    """The rows ``rows`` of a pre-processed GR00T batch: its images' patches are flattened across the batch (one
    image a row here), so they are cut by each image's patch count."""
    patches = batch["image_grid_thw"].prod(dim=1).tolist()
    starts = [sum(patches[:row]) for row in range(len(patches) + 1)]
    first, last, _ = rows.indices(len(patches))
    selected = {
        key: value[rows] if torch.is_tensor(value) and key != "pixel_values" else value for key, value in batch.items()
    }
    return {**selected, "pixel_values": batch["pixel_values"][starts[first] : starts[last]]}


def save_tiny_groot_student(checkpoint: Path, directory: Path, state_dim: int = STATE_DIM) -> Path:
    """A distilled tiny GR00T (phi_s non-zero) saved by snapflow with its processors (min-max statistics)."""
    from snapflow.adapters.lerobot import save_distilled, wrap_policy

    policy = build_tiny_groot(checkpoint, state_dim=state_dim)
    save_distilled(randomise_target_time(wrap_policy(policy)), directory)
    for processor in tiny_groot_processors(policy, state_dim):
        processor.save_pretrained(directory)
    return directory


__all__ = [
    "build_tiny_groot",
    "groot_rows",
    "raw_groot_batch",
    "save_tiny_groot_student",
    "tiny_groot_processors",
    "write_tiny_groot",
]
