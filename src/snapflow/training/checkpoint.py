"""Checkpoints: safetensors for every tensor (no pickle), JSON for everything else, written atomically.

A checkpoint is a directory holding ``policy.safetensors`` + ``policy.json`` and, for training
checkpoints, ``optimizer.safetensors`` + ``trainer_state.json``. It is assembled in a temporary
directory and renamed into place, and a run's ``latest.json`` is switched only after that, so a kill at
any moment leaves the last good checkpoint whole.
"""

from __future__ import annotations

import json
import os
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch
from safetensors import SafetensorError
from safetensors.torch import load_file, save_file
from torch import nn

from snapflow.data.demonstrations import NormalizationStats
from snapflow.io import write_json
from snapflow.nn.snapflow_policy import SnapFlowPolicy
from snapflow.policies.minivla import MiniVLA, MiniVLAConfig, MiniVLAProcessor

POLICY_WEIGHTS, POLICY_CONFIG = "policy.safetensors", "policy.json"
OPTIMIZER_STATE, TRAINER_STATE = "optimizer.safetensors", "trainer_state.json"
LATEST = "latest.json"
FORMAT = "snapflow-policy"
VERSION = 1


class CheckpointError(ValueError):
    """A checkpoint that is missing, corrupt, or does not match what it is loaded into."""


@dataclass
class LoadedPolicy:
    policy: SnapFlowPolicy
    processor: MiniVLAProcessor
    metadata: dict[str, Any]
    path: Path

    @property
    def val_fraction(self) -> float:
        """Share of each task's demonstration episodes the run held out (0.1 where the metadata predates it)."""
        return self.metadata.get("data", {}).get("val_fraction", 0.1)


def policy_metadata(policy: SnapFlowPolicy, processor: MiniVLAProcessor, **extra: Any) -> dict[str, Any]:
    return {
        "format": FORMAT, "version": VERSION, "policy": "minivla",
        "config": processor.config.to_dict(), "target_time": policy.target_time_embedding is not None,
        "stats": vars(processor.stats), **extra,
    }


def _read_json(path: Path) -> dict[str, Any]:
    if not path.is_file():
        raise CheckpointError(f"{path} not found")
    try:
        return json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as error:
        raise CheckpointError(f"{path} is corrupt (not JSON: {error})") from None


def read_tensors(path: Path) -> dict[str, torch.Tensor]:
    if not path.is_file():
        raise CheckpointError(f"{path} not found")
    try:
        return load_file(path)
    except (SafetensorError, OSError, ValueError, RuntimeError) as error:
        raise CheckpointError(f"{path} is corrupt or not a safetensors file ({error})") from None


def load_state_strict(module: nn.Module, tensors: dict[str, torch.Tensor], source: Path) -> None:
    """Load weights, naming every missing, unexpected or differently shaped tensor."""
    expected = module.state_dict()
    missing = sorted(set(expected) - set(tensors))
    unexpected = sorted(set(tensors) - set(expected))
    shapes = [f"{k}: checkpoint {tuple(tensors[k].shape)} vs model {tuple(v.shape)}" for k, v in expected.items() if k in tensors and tensors[k].shape != v.shape]
    if missing or unexpected or shapes:
        details = "; ".join(filter(None, [
            f"missing {missing[:5]}{'...' if len(missing) > 5 else ''}" if missing else "",
            f"unexpected {unexpected[:5]}{'...' if len(unexpected) > 5 else ''}" if unexpected else "",
            f"shape mismatch {shapes[:5]}" if shapes else "",
        ]))
        raise CheckpointError(f"{source} does not match the policy: {details}")
    module.load_state_dict(tensors, strict=True)


def resolve_checkpoint(path: str | Path) -> Path:
    """A checkpoint directory, or a run directory whose ``latest.json`` names one."""
    path = Path(path)
    if (path / POLICY_CONFIG).is_file():
        return path
    if (path / LATEST).is_file():
        return path / _read_json(path / LATEST)["checkpoint"]
    if not path.exists():
        raise CheckpointError(f"{path} does not exist")
    raise CheckpointError(f"{path} holds neither a checkpoint ({POLICY_CONFIG}) nor a run ({LATEST})")


def load_policy(path: str | Path, target_time: bool | None = None) -> LoadedPolicy:
    """Build the policy a checkpoint describes and load its weights.

    ``target_time=True`` on a checkpoint saved without phi_s (a teacher) adds a fresh, zero-initialised
    one: that is how distillation starts from the teacher.
    """
    directory = resolve_checkpoint(path)
    metadata = _read_json(directory / POLICY_CONFIG)
    if metadata.get("format") != FORMAT:
        raise CheckpointError(f"{directory / POLICY_CONFIG} is not a snapflow policy (format {metadata.get('format')!r})")
    if metadata.get("policy") != "minivla":
        raise CheckpointError(f"{directory / POLICY_CONFIG}: unknown policy {metadata.get('policy')!r}")
    for field in ("config", "stats", "target_time"):
        if field not in metadata:
            raise CheckpointError(f"{directory / POLICY_CONFIG} lacks the field {field!r}")
    try:
        config = MiniVLAConfig.from_dict(metadata["config"])
        processor = MiniVLAProcessor(config, NormalizationStats(**metadata["stats"]))
    except (TypeError, ValueError) as error:
        raise CheckpointError(f"{directory / POLICY_CONFIG}: invalid field: {error}") from None
    saved_target_time = bool(metadata["target_time"])
    policy = SnapFlowPolicy(MiniVLA(config), target_time=saved_target_time)
    load_state_strict(policy, read_tensors(directory / POLICY_WEIGHTS), directory / POLICY_WEIGHTS)
    if target_time and not saved_target_time:
        policy = SnapFlowPolicy(policy.model, target_time=True)
    elif target_time is False and saved_target_time:
        raise CheckpointError(f"{directory} is a SnapFlow student; it cannot be loaded without its target-time embedding")
    return LoadedPolicy(policy, processor, metadata, directory)


def optimizer_tensors(optimizer: torch.optim.Optimizer) -> tuple[dict[str, torch.Tensor], dict[str, Any]]:
    """Split an optimizer state into tensors (for safetensors) and JSON-able metadata."""
    state = optimizer.state_dict()
    tensors = {f"{index}.{key}": value.contiguous() for index, entry in state["state"].items() for key, value in entry.items() if torch.is_tensor(value)}
    scalars = {f"{index}.{key}": value for index, entry in state["state"].items() for key, value in entry.items() if not torch.is_tensor(value)}
    return tensors, {"param_groups": state["param_groups"], "scalars": scalars}


def restore_optimizer(optimizer: torch.optim.Optimizer, directory: Path) -> None:
    tensors = read_tensors(directory / OPTIMIZER_STATE)
    meta = _read_json(directory / TRAINER_STATE)["optimizer"]
    state: dict[int, dict[str, Any]] = {}
    for name, value in list(tensors.items()) + list(meta["scalars"].items()):
        index, key = name.split(".", 1)
        state.setdefault(int(index), {})[key] = value
    try:
        optimizer.load_state_dict({"state": state, "param_groups": meta["param_groups"]})
    except (ValueError, KeyError) as error:
        raise CheckpointError(f"{directory}: optimizer state does not match the trainable parameters ({error})") from None


def restore_training(run_directory: Path, policy: nn.Module, optimizer: torch.optim.Optimizer) -> dict[str, Any]:
    """Load the latest checkpoint of a run into ``policy`` and ``optimizer``; return its trainer state."""
    checkpoint = resolve_checkpoint(run_directory)
    load_state_strict(policy, read_tensors(checkpoint / POLICY_WEIGHTS), checkpoint / POLICY_WEIGHTS)
    restore_optimizer(optimizer, checkpoint)
    return {key: value for key, value in _read_json(checkpoint / TRAINER_STATE).items() if key != "optimizer"}


def save_checkpoint(
    directory: Path, policy: SnapFlowPolicy, metadata: dict[str, Any],
    optimizer: torch.optim.Optimizer | None = None, trainer_state: dict[str, Any] | None = None,
) -> Path:
    """Write a checkpoint directory atomically (temporary sibling, then rename)."""
    directory = Path(directory)
    temporary = directory.parent / f".{directory.name}.partial-{os.getpid()}"
    for stale in directory.parent.glob(f".{directory.name}.partial-*"):  # left by a writer that was killed
        shutil.rmtree(stale, ignore_errors=True)
    temporary.mkdir(parents=True)
    state = {key: value.detach().cpu().contiguous() for key, value in policy.state_dict().items()}
    save_file(state, temporary / POLICY_WEIGHTS)
    write_json(temporary / POLICY_CONFIG, metadata)
    if optimizer is not None:
        tensors, optimizer_meta = optimizer_tensors(optimizer)
        save_file({k: v.cpu() for k, v in tensors.items()}, temporary / OPTIMIZER_STATE)
        write_json(temporary / TRAINER_STATE, {**(trainer_state or {}), "optimizer": optimizer_meta})
    if directory.exists():  # re-saving the same name: move the old one aside first, drop it after the swap
        retired = directory.parent / f".{directory.name}.retired-{os.getpid()}"
        os.replace(directory, retired)
        os.replace(temporary, directory)
        shutil.rmtree(retired)
    else:
        os.replace(temporary, directory)
    return directory


def mark_latest(run_directory: Path, checkpoint: Path, keep: int) -> None:
    """Point ``latest.json`` at ``checkpoint``, then delete all but the ``keep`` newest step checkpoints."""
    write_json(run_directory / LATEST, {"checkpoint": str(checkpoint.relative_to(run_directory))})
    steps = sorted((run_directory / "checkpoints").glob("step_*"))
    for old in steps[: max(len(steps) - keep, 0)]:
        if old != checkpoint:
            shutil.rmtree(old)


__all__ = ["CheckpointError", "LoadedPolicy", "load_policy", "save_checkpoint", "mark_latest", "resolve_checkpoint", "policy_metadata", "restore_training"]
