"""A tiny LeRobot VLA-JEPA built fully offline (LeRobot >= 0.6.1): a random two-layer Qwen3-VL (the tiny GR00T's, with
weights) and a random one-layer V-JEPA 2 at 32 pixels, written to local folders, and LeRobot's VLAJEPAPolicy over them,
its world model on (VLA-JEPA's default)."""

from __future__ import annotations

from pathlib import Path

import torch

from tests.lerobot_tiny import randomise_target_time

STATE_DIM, ACTION_DIM, HORIZON, FRAMES = 6, 4, 4, 4
IMAGE_KEY, VLA_JEPA_IMAGE_SIZE = "observation.images.top", 32
TASKS = ["pick the red cube", "open the drawer", "push the blue cube", "place a cube"]


def write_tiny_backbones(directory: Path) -> tuple[Path, Path]:
    """The tiny Qwen3-VL and V-JEPA 2 folders (configs, random weights, processors) in ``directory``."""
    from snapflow.adapters.lerobot.vla_jepa_checkpoint import SIZES, write_random_vla_jepa

    assert SIZES["tiny"].frame_size == VLA_JEPA_IMAGE_SIZE  # the size the helpers below build for
    qwen, vjepa = write_random_vla_jepa(directory, "tiny", world_model=True)
    return qwen, vjepa


def build_tiny_vla_jepa(backbones: tuple[Path, Path], state_dim: int = STATE_DIM, **options):
    """LeRobot's VLAJEPAPolicy over the tiny backbone folders, in float32 on the CPU, for a ``state_dim``-D state, one
    32-pixel camera and 4-D actions, its world model reading 4 frames (two V-JEPA tubelets); ``options`` are more
    VLAJEPAConfig fields. The DiT's dropout is off, so that its samples are deterministic in training mode too."""
    from lerobot.configs.types import FeatureType, PolicyFeature
    from lerobot.policies.vla_jepa.configuration_vla_jepa import VLAJEPAConfig
    from lerobot.policies.vla_jepa.modeling_vla_jepa import VLAJEPAPolicy

    qwen, vjepa = backbones
    sizes = dict(
        action_model_type="DiT-test",  # two heads of 8
        action_num_layers=2,  # a cross-attention block, then a self-attention block
        action_hidden_size=24,
        action_dropout=0.0,
        num_embodied_action_tokens_per_instruction=4,
        num_action_tokens_per_timestep=2,
        predictor_depth=1,
        predictor_num_heads=2,
        repeated_diffusion_steps=2,
    )
    config = VLAJEPAConfig(
        qwen_model_name=str(qwen),
        jepa_encoder_name=str(vjepa),
        torch_dtype="float32",
        chunk_size=HORIZON,
        n_action_steps=HORIZON,
        num_video_frames=FRAMES,
        device="cpu",
        push_to_hub=False,
        input_features={
            "observation.state": PolicyFeature(type=FeatureType.STATE, shape=(state_dim,)),
            IMAGE_KEY: PolicyFeature(type=FeatureType.VISUAL, shape=(3, VLA_JEPA_IMAGE_SIZE, VLA_JEPA_IMAGE_SIZE)),
        },
        output_features={"action": PolicyFeature(type=FeatureType.ACTION, shape=(ACTION_DIM,))},
        **{**sizes, **options},
    )
    with torch.random.fork_rng(devices=[]):  # the action head's and the predictor's init, the same every build
        torch.manual_seed(0)
        return VLAJEPAPolicy(config)


def unit_statistics(state_dim: int = STATE_DIM) -> dict:
    """Statistics of unit scale for the state's mean-std and the action's min-max normalisation."""
    return {
        key: {"min": -torch.ones(dim), "max": torch.ones(dim), "mean": torch.zeros(dim), "std": torch.ones(dim)}
        for key, dim in (("observation.state", state_dim), ("action", ACTION_DIM))
    }


def tiny_vla_jepa_processors(policy, state_dim: int = STATE_DIM) -> tuple:
    """VLA-JEPA's pre- and post-processors for ``policy`` with :func:`unit_statistics`."""
    from lerobot.policies.vla_jepa.processor_vla_jepa import make_vla_jepa_pre_post_processors

    return make_vla_jepa_pre_post_processors(policy.config, dataset_stats=unit_statistics(state_dim))


def raw_vla_jepa_batch(batch_size: int = 4, seed: int = 0, state_dim: int = STATE_DIM, frames: int = 0) -> dict:
    """A raw LeRobot batch for the tiny VLA-JEPA's pre-processor: state, one camera in [0, 1], tasks and action chunks;
    with ``frames``, the camera's and the state's next frames too, as LeRobot's dataset gives them for the world
    model (``observation_delta_indices``), the current one first."""
    generator = torch.Generator().manual_seed(seed)
    steps = (frames,) if frames else ()
    size = VLA_JEPA_IMAGE_SIZE
    return {
        "observation.state": torch.rand(batch_size, *steps, state_dim, generator=generator) * 2 - 1,
        IMAGE_KEY: torch.rand(batch_size, *steps, 3, size, size, generator=generator),
        "task": [TASKS[row % len(TASKS)] for row in range(batch_size)],
        "action": torch.rand(batch_size, HORIZON, ACTION_DIM, generator=generator) * 2 - 1,
    }


def vla_jepa_rows(batch: dict, rows: slice) -> dict:
    """The rows ``rows`` of a pre-processed VLA-JEPA batch, its tasks (a list) included."""
    return {key: value[rows] if isinstance(value, (torch.Tensor, list)) else value for key, value in batch.items()}


def save_tiny_vla_jepa_student(backbones: tuple[Path, Path], directory: Path, state_dim: int = STATE_DIM) -> Path:
    """A distilled tiny VLA-JEPA (phi_s non-zero) saved by snapflow with its processors."""
    from snapflow.adapters.lerobot import save_distilled, wrap_policy

    policy = build_tiny_vla_jepa(backbones, state_dim=state_dim)
    save_distilled(randomise_target_time(wrap_policy(policy)), directory)
    for processor in tiny_vla_jepa_processors(policy, state_dim):
        processor.save_pretrained(directory)
    return directory


__all__ = [
    "build_tiny_vla_jepa",
    "raw_vla_jepa_batch",
    "save_tiny_vla_jepa_student",
    "tiny_vla_jepa_processors",
    "unit_statistics",
    "vla_jepa_rows",
    "write_tiny_backbones",
]
