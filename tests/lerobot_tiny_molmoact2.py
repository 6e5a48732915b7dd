"""A tiny LeRobot MolmoAct2 built fully offline (LeRobot >= 0.6.1): a random MolmoAct2 checkpoint (a one-layer vision
tower at 28 pixels, two language layers of 32, two expert blocks of 32, a word-level tokenizer with MolmoAct2's special
tokens) written to a local folder with its weights, which LeRobot's MolmoAct2Policy loads, and the policy over it."""

from __future__ import annotations

from pathlib import Path

import torch

from tests.lerobot_tiny import randomise_target_time

#: MolmoAct2 pads actions to 32; the tiny policy's robot has a 6-D state and 4-D actions in 4-action chunks
STATE_DIM, ACTION_DIM, HORIZON, MAX_ACTION_DIM = 6, 4, 4, 32
IMAGE_KEY, IMAGE_SIZE = "observation.images.top", 32
TASKS = ["pick the red cube", "open the drawer", "push the blue cube", "place a cube"]
#: the pre-processor's image tensors, laid out crop after crop over the whole batch (one crop an image here)
IMAGE_FIELDS = ("pixel_values", "image_token_pooling", "image_grids", "image_num_crops")


def write_tiny_molmoact2(directory: Path) -> Path:
    """The tiny MolmoAct2 checkpoint folder (config, random weights, tokenizer, processor config) in ``directory``."""
    from snapflow.adapters.lerobot.molmoact2_checkpoint import write_random_molmoact2

    return write_random_molmoact2(directory, "tiny")


def build_tiny_molmoact2(checkpoint: Path, state_dim: int = STATE_DIM, image_key: str = IMAGE_KEY, **options):
    """LeRobot's MolmoAct2Policy (about 110k parameters) over the tiny checkpoint folder ``checkpoint``, in float32 on
    the CPU, continuous actions only, for a ``state_dim``-D state, one 32-pixel camera (resized to 28) and 4-D
    actions; ``options`` are more MolmoAct2Config fields."""
    from lerobot.configs.types import FeatureType, PolicyFeature
    from lerobot.policies.molmoact2.configuration_molmoact2 import MolmoAct2Config
    from lerobot.policies.molmoact2.modeling_molmoact2 import MolmoAct2Policy

    config = MolmoAct2Config(
        checkpoint_path=str(checkpoint),
        action_mode="continuous",
        inference_action_mode="continuous",
        model_dtype="float32",
        chunk_size=HORIZON,
        n_action_steps=HORIZON,
        device="cpu",
        push_to_hub=False,
        input_features={
            "observation.state": PolicyFeature(type=FeatureType.STATE, shape=(state_dim,)),
            image_key: PolicyFeature(type=FeatureType.VISUAL, shape=(3, IMAGE_SIZE, IMAGE_SIZE)),
        },
        output_features={"action": PolicyFeature(type=FeatureType.ACTION, shape=(ACTION_DIM,))},
        # the checkpoint's own 10 steps, named: the contract sets a teacher's steps through this field
        **{"num_inference_steps": 10, **options},
    )
    return MolmoAct2Policy(config)


def unit_statistics(state_dim: int = STATE_DIM) -> dict:
    """Quantile statistics (MolmoAct2 normalises state and actions by their 1st and 99th percentiles) of [-1, 1]."""
    return {
        key: {"q01": torch.full((dim,), -1.0), "q99": torch.ones(dim), "min": -torch.ones(dim), "max": torch.ones(dim)}
        for key, dim in (("observation.state", state_dim), ("action", ACTION_DIM))
    }


def tiny_molmoact2_processors(policy, state_dim: int = STATE_DIM) -> tuple:
    """MolmoAct2's pre- and post-processors for ``policy`` with [-1, 1] quantile statistics."""
    from lerobot.policies.molmoact2.processor_molmoact2 import make_molmoact2_pre_post_processors

    return make_molmoact2_pre_post_processors(policy.config, dataset_stats=unit_statistics(state_dim))


def raw_molmoact2_batch(batch_size: int = 4, seed: int = 0, state_dim: int = STATE_DIM, actions: bool = True) -> dict:
    """A raw LeRobot batch for the tiny MolmoAct2's pre-processor: state, one camera in [0, 1], tasks and (unless
    ``actions`` is false) action chunks."""
    generator = torch.Generator().manual_seed(seed)
    batch = {
        "observation.state": torch.rand(batch_size, state_dim, generator=generator) * 2 - 1,
        IMAGE_KEY: torch.rand(batch_size, 3, IMAGE_SIZE, IMAGE_SIZE, generator=generator),
        "task": [TASKS[row % len(TASKS)] for row in range(batch_size)],
    }
    if actions:
        batch["action"] = torch.rand(batch_size, HORIZON, ACTION_DIM, generator=generator) * 2 - 1
    return batch


def molmoact2_rows(batch: dict, rows: slice) -> dict:
    """The rows ``rows`` of a pre-processed tiny MolmoAct2 batch: its image tensors, one crop and one pooled token an
    image and one image a row, are sliced like the rest; its tasks (a list) too."""
    return {key: value[rows] if isinstance(value, (torch.Tensor, list)) else value for key, value in batch.items()}


def save_tiny_molmoact2_student(checkpoint: Path, directory: Path, state_dim: int = STATE_DIM) -> Path:
    """A distilled tiny MolmoAct2 (phi_s non-zero) saved by snapflow with its processors (quantile statistics)."""
    from snapflow.adapters.lerobot import save_distilled, wrap_policy

    policy = build_tiny_molmoact2(checkpoint, state_dim=state_dim)
    save_distilled(randomise_target_time(wrap_policy(policy)), directory)
    for processor in tiny_molmoact2_processors(policy, state_dim):
        processor.save_pretrained(directory)
    return directory


__all__ = [
    "build_tiny_molmoact2",
    "molmoact2_rows",
    "raw_molmoact2_batch",
    "save_tiny_molmoact2_student",
    "tiny_molmoact2_processors",
    "unit_statistics",
    "write_tiny_molmoact2",
]
