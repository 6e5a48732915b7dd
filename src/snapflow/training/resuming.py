"""Where a training run starts and what it leaves to start again from: the trainer state, fresh or resumed from the
run's latest checkpoint (or from the copy of it kept in another folder, on another machine), and the checkpoint of a
step, saved whole by the main process and marked latest. The loop that calls them is :mod:`snapflow.training.trainer`.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from contextlib import nullcontext
from pathlib import Path
from typing import Any

import torch
from accelerate import Accelerator
from accelerate.optimizer import AcceleratedOptimizer
from torch import nn

from snapflow.policies.checkpoint import LATEST, CheckpointError
from snapflow.reporting.records import as_record
from snapflow.training.checkpoint import (
    install_checkpoint,
    keep_checkpoint,
    mark_latest,
    read_kept,
    restore_training,
    save_checkpoint,
)
from snapflow.training.config import TrainConfig
from snapflow.training.ema import WeightAverage


def continue_from_kept(accelerator: Accelerator, run_directory: Path, kept_in: Path, config: TrainConfig) -> None:
    """Install the checkpoint kept in ``kept_in`` as the latest of a run folder that has none (not a finished run's
    policy kept there, which holds nothing to resume)."""
    kept = read_kept(kept_in)
    if kept is None or kept[1].get("finished") or (run_directory / LATEST).is_file():
        return
    install_checkpoint(kept[0], run_directory, config.keep_checkpoints)
    accelerator.print(
        f"{run_directory} holds no checkpoint: continuing from the one kept in {kept_in} ({kept[0].name})"
    )


def keeping_each_checkpoint(kept_in: Path, then: Callable[[Path], None] | None) -> Callable[[Path], None]:
    """An ``on_checkpoint`` that keeps a copy of each checkpoint in ``kept_in``, then calls ``then``."""

    def on_checkpoint(checkpoint: Path) -> None:
        keep_checkpoint(checkpoint, kept_in, {})
        if then is not None:
            then(checkpoint)

    return on_checkpoint


def starting_state(
    accelerator: Accelerator,
    run_directory: Path,
    policy: nn.Module,
    optimizer: torch.optim.Optimizer,
    average: WeightAverage | None,
    config: TrainConfig,
    resume: bool,
) -> dict[str, Any]:
    """A fresh trainer state, or with ``resume`` the latest checkpoint's, loaded into ``policy``, ``optimizer`` and
    ``average``. Refuses to resume under other training settings, and to start over a run without ``resume``."""
    recorded = as_record(config)
    fresh = {"step": 0, "history": [], "validation": [], "train_config": recorded, "wall_time_s": 0.0}
    if not (run_directory / LATEST).is_file():
        if resume:
            accelerator.print(f"nothing to resume in {run_directory}; starting at step 0")
        return fresh
    if not resume:
        raise FileExistsError(
            f"{run_directory} already holds a run; pass --resume to continue it or choose another --output"
        )
    state, saved_average = restore_training(run_directory, policy, optimizer)
    saved = state["train_config"]
    if saved != recorded:
        changed = sorted(key for key in recorded.keys() | saved.keys() if saved.get(key) != recorded.get(key))
        raise CheckpointError(
            f"cannot resume {run_directory}: training settings differ from the checkpoint's in {changed}"
        )
    if average is not None and saved_average is not None:
        average.average = saved_average
    accelerator.print(f"resuming {run_directory} at step {state['step']}")
    return state


def save_run_checkpoint(
    accelerator: Accelerator,
    module: nn.Module,
    optimizer: AcceleratedOptimizer,
    average: WeightAverage | None,
    state: dict[str, Any],
    step: int,
    started: float,
    run_directory: Path,
    metadata: dict[str, Any],
    config: TrainConfig,
) -> Path | None:
    """Checkpoint the run at ``step`` from the main process (its ``state`` brought to that step, its wall time counted
    from ``started``) and mark it latest, keeping ``config.keep_checkpoints``; every process waits for it. With a
    weight average, the average is saved as the policy (what evaluation reads) and the raw weights beside it (what
    training resumes from). Returns the checkpoint's folder on the main process, None on the others."""
    path = None
    if accelerator.is_main_process:
        state.update(step=step, wall_time_s=time.perf_counter() - started)
        with average.applied() if average is not None else nullcontext() as raw:
            path = save_checkpoint(
                run_directory / "checkpoints" / f"step_{step:07d}",
                accelerator.unwrap_model(module).policy,
                metadata,
                optimizer.optimizer,
                state,
                training_weights=raw,
            )
        mark_latest(run_directory, path, config.keep_checkpoints)
    accelerator.wait_for_everyone()
    return path


__all__ = ["continue_from_kept", "keeping_each_checkpoint", "save_run_checkpoint", "starting_state"]
