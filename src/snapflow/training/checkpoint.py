"""Training checkpoints: the policy's files (:mod:`snapflow.policies.checkpoint`) plus ``optimizer.safetensors`` and
``trainer_state.json``, written atomically. A run that averages its weights (``TrainConfig.ema_decay``) saves the
average as the policy and the raw trained weights in ``training_weights.safetensors``, which resuming continues from.

A checkpoint is assembled in a temporary directory and renamed into place, and the run's ``latest.json`` is
switched only after that, so a kill at any moment leaves the last good checkpoint whole.
"""

from __future__ import annotations

import json
import os
import shutil
from collections.abc import Callable
from pathlib import Path
from typing import Any

import torch
from safetensors.torch import save_file
from torch import nn

from snapflow.policies.checkpoint import (
    LATEST,
    POLICY_CONFIG,
    POLICY_WEIGHTS,
    CheckpointError,
    load_state_strict,
    read_json,
    read_tensors,
    resolve_checkpoint,
    write_weights,
)
from snapflow.reporting.archive import archived_hint
from snapflow.reporting.files import write_json

OPTIMIZER_STATE, TRAINER_STATE = "optimizer.safetensors", "trainer_state.json"
TRAINING_WEIGHTS = "training_weights.safetensors"
#: the name of a step checkpoint starts with this (``step_0005000``; a kept lerobot-train step, ``step_004000``)
STEP_PREFIX = "step_"
KEPT = "kept.json"  # beside a kept checkpoint: its name and what its keeper noted of it


def optimizer_tensors(state: dict[str, Any]) -> tuple[dict[str, torch.Tensor], dict[str, Any]]:
    """Split an optimizer's ``state_dict()`` into tensors (for safetensors) and JSON-able metadata."""
    tensors = {
        f"{index}.{key}": value.contiguous()
        for index, entry in state["state"].items()
        for key, value in entry.items()
        if torch.is_tensor(value)
    }
    scalars = {
        f"{index}.{key}": value
        for index, entry in state["state"].items()
        for key, value in entry.items()
        if not torch.is_tensor(value)
    }
    return tensors, {"param_groups": state["param_groups"], "scalars": scalars}


def read_optimizer_state(directory: Path) -> dict[str, Any]:
    """The optimizer ``state_dict()`` a checkpoint saved (:func:`optimizer_tensors`), its parameters by position."""
    tensors = read_tensors(directory / OPTIMIZER_STATE)
    meta = read_json(directory / TRAINER_STATE)["optimizer"]
    state: dict[int, dict[str, Any]] = {}
    for name, value in list(tensors.items()) + list(meta["scalars"].items()):
        index, key = name.split(".", 1)
        state.setdefault(int(index), {})[key] = value
    return {"state": state, "param_groups": meta["param_groups"]}


def restore_optimizer(directory: Path, load: Callable[[dict[str, Any]], Any]) -> None:
    """Hand the optimizer state a checkpoint saved to ``load`` (an optimizer's ``load_state_dict``, or a sharded
    one's loader), naming a mismatch with the trainable parameters as the checkpoint's."""
    try:
        load(read_optimizer_state(directory))
    except (ValueError, KeyError, IndexError) as error:
        raise CheckpointError(
            f"{directory}: optimizer state does not match the trainable parameters ({error})"
        ) from None


def restore_weights(
    run_directory: Path, policy: nn.Module
) -> tuple[Path, dict[str, Any], dict[str, torch.Tensor] | None]:
    """Load the latest checkpoint of a run into ``policy`` (the raw trained weights where it saved an average as the
    policy); return the checkpoint, its trainer state and that average by parameter name (None if none). Its
    optimizer state is :func:`restore_optimizer`'s, once the optimizer is made."""
    checkpoint = resolve_checkpoint(run_directory)
    load_state_strict(policy, read_tensors(checkpoint / POLICY_WEIGHTS), checkpoint / POLICY_WEIGHTS)
    state = {key: value for key, value in read_json(checkpoint / TRAINER_STATE).items() if key != "optimizer"}
    if not (checkpoint / TRAINING_WEIGHTS).is_file():
        return checkpoint, state, None
    raw = read_tensors(checkpoint / TRAINING_WEIGHTS)
    parameters = dict(policy.named_parameters())
    unknown = sorted(set(raw) - set(parameters))
    if unknown:
        raise CheckpointError(f"{checkpoint / TRAINING_WEIGHTS} names parameters the policy lacks: {unknown[:5]}")
    average = {name: parameters[name].detach().clone() for name in raw}
    with torch.no_grad():
        for name, value in raw.items():
            parameters[name].copy_(value)
    return checkpoint, state, average


def save_checkpoint(
    directory: Path,
    weights: dict[str, torch.Tensor],
    metadata: dict[str, Any],
    optimizer_state: dict[str, Any] | None = None,
    trainer_state: dict[str, Any] | None = None,
    training_weights: dict[str, torch.Tensor] | None = None,
) -> Path:
    """Write a checkpoint directory atomically (temporary sibling, then rename): the policy's ``weights``
    (:func:`~snapflow.policies.checkpoint.untied_state`), an optimizer's ``state_dict()``; ``training_weights``: the
    raw trained weights by parameter name, where ``weights`` are their average."""
    directory = Path(directory)
    temporary = _temporary_sibling(directory)
    write_weights(temporary, weights, metadata)
    if optimizer_state is not None:
        tensors, optimizer_meta = optimizer_tensors(optimizer_state)
        save_file({k: v.cpu() for k, v in tensors.items()}, temporary / OPTIMIZER_STATE)
        write_json(temporary / TRAINER_STATE, {**(trainer_state or {}), "optimizer": optimizer_meta})
    if training_weights is not None:
        save_file({k: v.detach().cpu().contiguous() for k, v in training_weights.items()}, temporary / TRAINING_WEIGHTS)
    return _into_place(temporary, directory)


def copy_checkpoint(
    checkpoint: Path, destination: Path, policy_only: bool = False, prepare: Callable[[Path], Any] | None = None
) -> Path:
    """Copy the checkpoint folder ``checkpoint`` to ``destination`` atomically, replacing what is there, its
    sub-folders included (a LeRobot policy's local VLM); with ``policy_only``, only the policy's files (what
    evaluation and distillation read), not what resuming reads. ``prepare`` is given the copy before it is put in
    place (a LeRobot policy folder takes its VLM inside: :func:`snapflow.adapters.lerobot.local_vlm.bundle_vlm`)."""
    temporary = _temporary_sibling(Path(destination))
    for entry in sorted(Path(checkpoint).iterdir()):
        if entry.is_file() and (not policy_only or entry.name in (POLICY_CONFIG, POLICY_WEIGHTS)):
            shutil.copy2(entry, temporary / entry.name)
        elif entry.is_dir() and not policy_only and not entry.name.startswith("."):
            shutil.copytree(entry, temporary / entry.name)
    if prepare is not None:
        prepare(temporary)
    return _into_place(temporary, Path(destination))


def _temporary_sibling(directory: Path) -> Path:
    """A new empty folder beside ``directory`` to assemble it in (any left by a writer that was killed removed)."""
    temporary = directory.parent / f".{directory.name}.partial-{os.getpid()}"
    for stale in directory.parent.glob(f".{directory.name}.partial-*"):
        shutil.rmtree(stale, ignore_errors=True)
    temporary.mkdir(parents=True)
    return temporary


def _into_place(temporary: Path, directory: Path) -> Path:
    """Rename the assembled ``temporary`` to ``directory``; an existing one is moved aside first, dropped after."""
    if directory.exists():
        retired = directory.parent / f".{directory.name}.retired-{os.getpid()}"
        os.replace(directory, retired)
        os.replace(temporary, directory)
        shutil.rmtree(retired)
    else:
        os.replace(temporary, directory)
    return directory


def keep_checkpoint(
    checkpoint: Path,
    directory: Path,
    note: dict[str, Any],
    policy_only: bool = False,
    prepare: Callable[[Path], Any] | None = None,
    name: str | None = None,
) -> Path:
    """Make a copy of ``checkpoint`` the one checkpoint kept in ``directory`` (a folder to commit or carry to another
    machine), with ``note`` recorded beside it (:func:`read_kept` returns both); the previous one is removed only
    once the copy and its note are whole, so a kill at any moment leaves a checkpoint that the note names.
    ``prepare``: as :func:`copy_checkpoint`'s; ``name``: the copy's (default: the checkpoint's own)."""
    kept = copy_checkpoint(checkpoint, Path(directory) / (name or Path(checkpoint).name), policy_only, prepare)
    write_json(Path(directory) / KEPT, {"checkpoint": kept.name, **note})
    for other in Path(directory).glob(f"{STEP_PREFIX}*"):
        if other != kept:
            shutil.rmtree(other)
    return kept


def read_kept(directory: Path) -> tuple[Path, dict[str, Any]] | None:
    """The checkpoint kept in ``directory`` by :func:`keep_checkpoint` and its note, or None where none is."""
    try:
        note = json.loads((Path(directory) / KEPT).read_text())
    except (FileNotFoundError, json.JSONDecodeError):
        return None
    checkpoint = Path(directory) / note.pop("checkpoint")
    # a snapflow checkpoint's weights, a LeRobot policy folder's, or a lerobot-train step's (under pretrained_model/):
    # archiving takes every safetensors file out
    if checkpoint.is_dir() and not any(checkpoint.rglob("*.safetensors")) and (hint := archived_hint(checkpoint)):
        # never train again what history keeps: hours of work, where one command brings the weights back
        raise FileNotFoundError(f"the kept checkpoint {checkpoint} lacks its weights{hint}")
    return (checkpoint, note) if checkpoint.is_dir() else None


def install_checkpoint(checkpoint: Path, run_directory: Path, keep: int) -> Path:
    """Copy a checkpoint kept elsewhere into ``run_directory`` as its latest, which training resumes from (``keep``:
    the step checkpoints a run keeps)."""
    installed = copy_checkpoint(checkpoint, Path(run_directory) / "checkpoints" / Path(checkpoint).name)
    mark_latest(Path(run_directory), installed, keep)
    return installed


def mark_latest(run_directory: Path, checkpoint: Path, keep: int) -> None:
    """Point ``latest.json`` at ``checkpoint``, then delete all but the ``keep`` newest step checkpoints."""
    write_json(run_directory / LATEST, {"checkpoint": str(checkpoint.relative_to(run_directory))})
    steps = sorted((run_directory / "checkpoints").glob(f"{STEP_PREFIX}*"))
    for old in steps[: max(len(steps) - keep, 0)]:
        if old != checkpoint:
            shutil.rmtree(old)


__all__ = [
    "OPTIMIZER_STATE",
    "STEP_PREFIX",
    "TRAINER_STATE",
    "TRAINING_WEIGHTS",
    "save_checkpoint",
    "copy_checkpoint",
    "keep_checkpoint",
    "read_kept",
    "install_checkpoint",
    "mark_latest",
    "restore_optimizer",
    "restore_weights",
]
