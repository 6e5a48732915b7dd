"""A tiny LeRobot EO-1 built fully offline (LeRobot >= 0.6.1): a random Qwen2.5-VL (one vision block of 16, two
Qwen2.5 layers of 32, a word-level tokenizer with Qwen's and EO-1's special tokens, Qwen's chat template) written to a
local folder with its weights and processor, which EO-1 loads, and LeRobot's EO1Policy over it."""

from __future__ import annotations

from pathlib import Path

import torch

from tests.lerobot_tiny import randomise_target_time

#: EO-1 pads state and action to these widths; the tiny policy's own are narrower, so the padding is exercised
MAX_STATE_DIM, MAX_ACTION_DIM, STATE_DIM, ACTION_DIM, CHUNK = 8, 8, 6, 4, 4
#: the tiny dataset's camera (tests/lerobot_tiny.py), which the tiny Qwen2.5-VL's processor resizes to 56 pixels
IMAGE_KEY, EO1_IMAGE_SIZE = "observation.images.top", 64
#: prompts of three lengths: a batch's rows are padded (left for sampling, right for training)
TASKS = ["pick the red cube", "open the drawer", "push the blue cube to the drawer", "place a cube"]


def write_tiny_qwen2_5_vl(directory: Path) -> Path:
    """The tiny Qwen2.5-VL folder (config, random weights, processor) in ``directory``."""
    from snapflow.adapters.lerobot.eo1_checkpoint import write_random_qwen2_5_vl

    return write_random_qwen2_5_vl(directory, "tiny")


def build_tiny_eo1(vlm: Path, state_dim: int = STATE_DIM, **options):
    """LeRobot's EO1Policy (about 53k parameters) over the tiny Qwen2.5-VL folder ``vlm``, in float32 on the CPU, for
    a ``state_dim``-D state, one 64-pixel camera and 4-D actions; ``options`` are more EO1Config fields."""
    from lerobot.configs.types import FeatureType, PolicyFeature
    from lerobot.policies.eo1.configuration_eo1 import EO1Config
    from lerobot.policies.eo1.modeling_eo1 import EO1Policy

    from snapflow.adapters.lerobot.eo1_checkpoint import SIZES

    low, high = SIZES["tiny"].pixels
    config = EO1Config(
        vlm_base=str(vlm),
        dtype="float32",
        image_min_pixels=low,
        image_max_pixels=high,
        chunk_size=CHUNK,
        n_action_steps=CHUNK,
        max_state_dim=MAX_STATE_DIM,
        max_action_dim=MAX_ACTION_DIM,
        device="cpu",
        push_to_hub=False,
        input_features={
            "observation.state": PolicyFeature(type=FeatureType.STATE, shape=(state_dim,)),
            IMAGE_KEY: PolicyFeature(type=FeatureType.VISUAL, shape=(3, EO1_IMAGE_SIZE, EO1_IMAGE_SIZE)),
        },
        output_features={"action": PolicyFeature(type=FeatureType.ACTION, shape=(ACTION_DIM,))},
        **options,
    )
    with torch.random.fork_rng(devices=[]):  # the flow head's init, the same every build
        torch.manual_seed(0)
        return EO1Policy(config)


def tiny_eo1_processors(policy, state_dim: int = STATE_DIM) -> tuple:
    """EO-1's pre- and post-processors for ``policy`` with unit mean-std statistics."""
    from lerobot.policies.eo1.processor_eo1 import make_eo1_pre_post_processors

    stats = {
        key: {"mean": torch.zeros(dim), "std": torch.ones(dim)}
        for key, dim in (("observation.state", state_dim), ("action", ACTION_DIM))
    }
    return make_eo1_pre_post_processors(policy.config, dataset_stats=stats)


def raw_eo1_batch(batch_size: int = 4, seed: int = 0, state_dim: int = STATE_DIM, actions: bool = True) -> dict:
    """A raw LeRobot batch for the tiny EO-1's pre-processor: state, one camera in [0, 1], tasks and (where
    ``actions``) action chunks."""
    generator = torch.Generator().manual_seed(seed)
    batch = {
        "observation.state": torch.randn(batch_size, state_dim, generator=generator),
        IMAGE_KEY: torch.rand(batch_size, 3, EO1_IMAGE_SIZE, EO1_IMAGE_SIZE, generator=generator),
        "task": [TASKS[row % len(TASKS)] for row in range(batch_size)],
    }
    chunks = torch.randn(batch_size, CHUNK, ACTION_DIM, generator=generator)
    return {**batch, "action": chunks} if actions else batch


def eo1_batch(policy, batch_size: int = 4, seed: int = 0, training: bool = False) -> dict:
    """A pre-processed tiny EO-1 batch of ``batch_size`` rows as the pre-processor lays it out for sampling (prompts
    left-padded, action spans aligned) with the normalised chunks added; or, where ``training``, as it lays out a
    training batch (prompts right-padded: each row's action span where its prompt ends)."""
    preprocessor, _ = tiny_eo1_processors(policy)
    trained = preprocessor(raw_eo1_batch(batch_size, seed))
    return (
        trained
        if training
        else {**preprocessor(raw_eo1_batch(batch_size, seed, actions=False)), "action": trained["action"]}
    )


def eo1_rows(batch: dict, rows: slice) -> dict:
    """The rows ``rows`` of a pre-processed EO-1 batch: Qwen's processor concatenates every image's patches along one
    axis, so a row's patches are cut by the images' grids."""
    patches = batch["image_grid_thw"].prod(-1)  # one image a row (one camera)
    ends = patches.cumsum(0)
    first, last = range(len(patches))[rows][0], range(len(patches))[rows][-1]
    picked = {"pixel_values": batch["pixel_values"][ends[first] - patches[first] : ends[last]]}
    return {
        key: picked.get(key, value[rows] if isinstance(value, (torch.Tensor, list)) else value)
        for key, value in batch.items()
    }


def save_tiny_eo1_student(vlm: Path, directory: Path, state_dim: int = STATE_DIM) -> Path:
    """A distilled tiny EO-1 (phi_s non-zero) saved by snapflow with its processors (unit statistics)."""
    from snapflow.adapters.lerobot import save_distilled, wrap_policy

    policy = build_tiny_eo1(vlm, state_dim=state_dim)
    save_distilled(randomise_target_time(wrap_policy(policy)), directory)
    for processor in tiny_eo1_processors(policy, state_dim):
        processor.save_pretrained(directory)
    return directory


__all__ = [
    "build_tiny_eo1",
    "eo1_batch",
    "eo1_rows",
    "raw_eo1_batch",
    "save_tiny_eo1_student",
    "tiny_eo1_processors",
    "write_tiny_qwen2_5_vl",
]
