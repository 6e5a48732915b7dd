"""A distilled LeRobot policy on disk: LeRobot's own layout (``config.json`` + ``model.safetensors`` with phi_s
inside) plus a marker that says which adapter rebuilds it."""

from __future__ import annotations

import json
from pathlib import Path

from snapflow.adapters.lerobot.base import LeRobotFlowPolicy
from snapflow.adapters.lerobot.registry import adapter_class
from snapflow.flow.modes import SNAPFLOW_1, SamplingMode
from snapflow.policies.checkpoint import CheckpointError, load_state_strict, read_tensors
from snapflow.reporting.files import write_json

SNAPFLOW_MARKER = "snapflow.json"


def save_distilled(adapter: LeRobotFlowPolicy, directory: str | Path) -> Path:
    directory = Path(directory)
    adapter.policy.save_pretrained(directory)
    write_json(
        directory / SNAPFLOW_MARKER, {"format": "snapflow-lerobot", "policy": adapter.policy_type, "target_time": True}
    )
    return directory


def load_distilled(directory: str | Path, mode: SamplingMode = SNAPFLOW_1) -> LeRobotFlowPolicy:
    """Rebuild a saved SnapFlow policy, load every tensor strictly, and make LeRobot's own action API sample
    with ``mode`` (SnapFlow 1-NFE by default). (LeRobot's ``from_pretrained`` loads SmolVLA non-strictly, so on
    its own it would silently drop phi_s and give back the teacher.)"""
    from lerobot.configs.policies import PreTrainedConfig
    from lerobot.policies.factory import get_policy_class

    directory = Path(directory)
    marker = directory / SNAPFLOW_MARKER
    if not marker.is_file():
        raise CheckpointError(f"{directory} is not a SnapFlow-distilled LeRobot policy (no {SNAPFLOW_MARKER})")
    try:
        policy_type = json.loads(marker.read_text())["policy"]
    except (json.JSONDecodeError, KeyError, TypeError) as error:
        raise CheckpointError(f"{marker} is corrupt ({error})") from None
    config = PreTrainedConfig.from_pretrained(directory)
    if config.type != policy_type:
        raise CheckpointError(f"{directory} holds a {config.type!r} config but its marker says {policy_type!r}")
    adapter = adapter_class(policy_type)(get_policy_class(policy_type)(config))
    load_state_strict(adapter.policy, read_tensors(directory / "model.safetensors"), directory / "model.safetensors")
    adapter.use_sampling_mode(mode)
    return adapter


__all__ = ["SNAPFLOW_MARKER", "save_distilled", "load_distilled"]
