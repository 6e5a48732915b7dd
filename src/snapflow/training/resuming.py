"""Where a training run starts and what it leaves to start again from: the trainer state, fresh or resumed from the
run's latest checkpoint (or from the copy of it kept in another folder, on another machine), and the checkpoint of a
step, saved whole by the main process (a sharded student's weights and optimizer state gathered there first) and
marked latest. The loop that calls them is :mod:`snapflow.training.trainer`.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from contextlib import nullcontext
from functools import partial
from pathlib import Path
from typing import Any

import torch
from accelerate import Accelerator
from accelerate.optimizer import AcceleratedOptimizer
from torch import nn

from snapflow.policies.checkpoint import LATEST, CheckpointError, untied_state
from snapflow.reporting.records import as_record
from snapflow.training.checkpoint import (
    STEP_PREFIX,
    install_checkpoint,
    keep_checkpoint,
    mark_latest,
    read_kept,
    restore_optimizer,
    restore_weights,
    save_checkpoint,
)
from snapflow.training.config import TrainConfig
from snapflow.training.ema import WeightAverage
from snapflow.training.sharding import (
    gathered_optimizer_state,
    gathered_weights,
    is_sharded,
    load_optimizer_state,
    shard_module,
)


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
    accelerator: Accelerator, run_directory: Path, policy: nn.Module, config: TrainConfig, resume: bool
) -> tuple[dict[str, Any], Path | None, dict[str, torch.Tensor] | None]:
    """A fresh trainer state, or with ``resume`` the latest checkpoint's, its weights loaded into ``policy``; with the
    checkpoint to restore the optimizer from (None when fresh) and the weight average it saved (None if none).
    Refuses to resume under other training settings, and to start over a run without ``resume``."""
    recorded = as_record(config)
    fresh = {"step": 0, "history": [], "validation": [], "train_config": recorded, "wall_time_s": 0.0}
    if not (run_directory / LATEST).is_file():
        if resume:
            accelerator.print(f"nothing to resume in {run_directory}; starting at step 0")
        return fresh, None, None
    if not resume:
        raise FileExistsError(
            f"{run_directory} already holds a run; pass --resume to continue it or choose another --output"
        )
    checkpoint, state, saved_average = restore_weights(run_directory, policy)
    saved = state["train_config"]
    if saved != recorded:
        changed = sorted(key for key in recorded.keys() | saved.keys() if saved.get(key) != recorded.get(key))
        raise CheckpointError(
            f"cannot resume {run_directory}: training settings differ from the checkpoint's in {changed}"
        )
    accelerator.print(f"resuming {run_directory} at step {state['step']}")
    return state, checkpoint, saved_average


def _freeze_all_but(policy: nn.Module, trainable: list[nn.Parameter] | None) -> list[str]:
    """Freeze every parameter of ``policy`` but ``trainable`` (default: none frozen); the trained ones' names, in the
    order given (the optimizer's, which its saved state keys by position)."""
    chosen = trainable if trainable is not None else list(policy.parameters())
    chosen_ids = {id(parameter) for parameter in chosen}
    for parameter in policy.parameters():
        parameter.requires_grad_(id(parameter) in chosen_ids)
    names = {id(parameter): name for name, parameter in policy.named_parameters()}
    return [names[id(parameter)] for parameter in chosen]


def _optimiser(
    policy: nn.Module, trained: list[str], config: TrainConfig
) -> tuple[torch.optim.AdamW, WeightAverage | None]:
    """AdamW over the parameters of ``policy`` named ``trained``, in that order, and their weight average where
    ``config`` keeps one (made after sharding, which replaces the parameters)."""
    parameters = dict(policy.named_parameters())
    chosen = {name: parameters[name] for name in trained}
    optimizer = torch.optim.AdamW(list(chosen.values()), lr=config.learning_rate, weight_decay=config.weight_decay)
    return optimizer, None if config.ema_decay is None else WeightAverage(chosen, config.ema_decay)


def start_run(
    accelerator: Accelerator,
    module: nn.Module,
    trainable: list[nn.Parameter] | None,
    config: TrainConfig,
    run_directory: Path,
    resume: bool,
    shard: bool,
) -> tuple[dict[str, Any], nn.Module, AcceleratedOptimizer, WeightAverage | None]:
    """Where a run starts: the trainer state (fresh or resumed: :func:`starting_state`), ``module`` (its ``policy``
    trained) as the steps run it (wrapped for data parallelism, or sharded), its optimizer, prepared by Accelerate, and
    its weight average. The weights are loaded before sharding and the optimizer made after, over the new parameters."""
    policy = module.policy
    trained = _freeze_all_but(policy, trainable)
    state, checkpoint, saved_average = starting_state(accelerator, run_directory, policy, config, resume)
    if shard:
        shard_module(module, accelerator)
    optimizer, average = _optimiser(policy, trained, config)
    if checkpoint is not None:
        load = partial(load_optimizer_state, module, optimizer) if shard else optimizer.load_state_dict
        restore_optimizer(checkpoint, load)
        if average is not None and saved_average is not None:
            average.average = saved_average
    if shard:  # Accelerate would wrap a sharded module again for data parallelism: it prepares the optimizer only
        return state, module, accelerator.prepare(optimizer), average
    module, optimizer = accelerator.prepare(module, optimizer)
    return state, module, optimizer, average


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
    """Checkpoint the run at ``step`` from the main process (``state`` brought to that step on every process, its wall
    time counted from ``started``) and mark it latest, keeping ``config.keep_checkpoints``; every process waits for it. With a
    weight average, the average is saved as the policy (what evaluation reads) and the raw weights beside it (what
    training resumes from). Returns the checkpoint's folder on the main process, None on the others."""
    path = None
    state.update(step=step, wall_time_s=time.perf_counter() - started)  # every process returns the run's state
    policy, sharded = accelerator.unwrap_model(module).policy, is_sharded(module)
    # a sharded student is gathered on the main process, every process taking part (it keeps no average: refused)
    gathered = (gathered_weights(policy), gathered_optimizer_state(module, optimizer.optimizer)) if sharded else None
    if accelerator.is_main_process:
        with average.applied() if average is not None else nullcontext() as raw:
            weights, optimizer_state = gathered or (untied_state(policy), optimizer.optimizer.state_dict())
            path = save_checkpoint(
                run_directory / "checkpoints" / f"{STEP_PREFIX}{step:07d}",
                weights,
                metadata,
                optimizer_state,
                state,
                training_weights=raw,
            )
        mark_latest(run_directory, path, config.keep_checkpoints)
    accelerator.wait_for_everyone()
    return path


__all__ = ["continue_from_kept", "keeping_each_checkpoint", "save_run_checkpoint", "start_run", "starting_state"]
