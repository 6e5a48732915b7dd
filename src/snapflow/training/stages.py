"""Training a built-in policy on demonstrations: the flow-matching teacher, then its SnapFlow student.

Each function is one pipeline stage that the CLI, the demo and the sweeps call; the teacher's default training
settings are :mod:`snapflow.training.config`'s, the student's the default recipe's (:mod:`snapflow.training.recipes`).
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import torch

from snapflow.data.chunks import split_chunk_data
from snapflow.data.demonstrations import Demonstrations
from snapflow.errors import InvalidInputError
from snapflow.flow.time_sampling import time_sampler_for
from snapflow.nn.snapflow_policy import SnapFlowPolicy
from snapflow.objective.snapflow import SnapFlowObjective
from snapflow.policies.checkpoint import load_policy, policy_metadata
from snapflow.policies.configuration import PolicyConfig
from snapflow.policies.factory import default_config, fit_processor, make_model
from snapflow.reporting.records import as_record
from snapflow.training.config import TEACHER_TRAINING, VAL_FRACTION, TrainConfig
from snapflow.training.recipes import DEFAULT_RECIPE, RECIPES, DistillSettings
from snapflow.training.trainer import train


def policy_config_for(
    policy_type: str, demonstrations: Demonstrations, state_dim: int | None = None, **overrides: Any
) -> PolicyConfig:
    """The default configuration of the registered policy ``policy_type`` for ``demonstrations``: their actions, their
    tasks' instructions and their state (its leading ``state_dim`` entries; default all); ``overrides`` set fields."""
    return default_config(
        policy_type,
        state_dim or demonstrations.states.shape[1],
        demonstrations.actions.shape[1],
        list(demonstrations.instructions.values()),
        **overrides,
    )


def teacher_objective(config: TrainConfig) -> SnapFlowObjective:
    """A built-in teacher's objective: plain flow matching (alpha = 1) at times drawn from ``config``'s
    ``time_distribution``."""
    return SnapFlowObjective(alpha=1.0, time_sampler=time_sampler_for(config.time_distribution))


def train_teacher(
    data: str | Path,
    output: str | Path,
    policy_config: PolicyConfig,
    config: TrainConfig = TEACHER_TRAINING,
    val_fraction: float = VAL_FRACTION,
    resume: bool = False,
    progress: bool = True,
    on_checkpoint: Callable[[Path], None] | None = None,
    keep_progress: str | Path | None = None,
) -> dict[str, Any]:
    """Plain flow matching (alpha = 1) of the registered policy ``policy_config`` configures, on the demonstrations,
    at times drawn from ``config.time_distribution`` (recorded in the checkpoint); normalisation from the training
    episodes. ``on_checkpoint``, ``keep_progress``: as :func:`~snapflow.training.trainer.train`'s."""
    if not 0 <= val_fraction < 1:
        raise InvalidInputError(f"val_fraction must be in [0, 1), got {val_fraction}")
    demonstrations = Demonstrations.load(data)
    train_episodes, _ = demonstrations.split(val_fraction)
    processor = fit_processor(policy_config, demonstrations, train_episodes)
    torch.manual_seed(config.seed)
    policy = SnapFlowPolicy(make_model(policy_config), target_time=False)
    train_data, val_data = split_chunk_data(demonstrations, processor, val_fraction)
    metadata = policy_metadata(
        policy,
        processor,
        stage="teacher",
        data={"path": str(data), "val_fraction": val_fraction, "env": demonstrations.env},
        time_distribution=config.time_distribution,
    )
    return train(
        policy,
        teacher_objective(config),
        train_data,
        val_data,
        config,
        output,
        metadata,
        resume=resume,
        progress=progress,
        holder="snapflow train",
        on_checkpoint=on_checkpoint,
        keep_progress=keep_progress,
    )


def distill(
    teacher: str | Path,
    data: str | Path,
    output: str | Path,
    config: TrainConfig | None = None,
    settings: DistillSettings | None = None,
    val_fraction: float | None = None,
    resume: bool = False,
    progress: bool = True,
    on_checkpoint: Callable[[Path], None] | None = None,
    keep_progress: str | Path | None = None,
    shard: bool = False,
) -> dict[str, Any]:
    """SnapFlow (or a baseline, see ``DistillSettings``): the student starts as the teacher plus a zero-initialised
    phi_s; prefix frozen by default; its flow-matching rows draw the teacher's own times (its checkpoint's
    ``time_distribution``, recorded in the student's too). ``config`` and ``settings`` default to the default recipe's
    (:data:`~snapflow.training.recipes.RECIPES`). ``on_checkpoint``, ``keep_progress``, ``shard``: as
    :func:`~snapflow.training.trainer.train`'s."""
    recipe = RECIPES[DEFAULT_RECIPE]
    config, settings = config or recipe.train, settings or recipe.distill
    config.check_student("distill")
    loaded = load_policy(teacher, target_time=settings.target_time)
    demonstrations = Demonstrations.load(data)
    if val_fraction is None:
        val_fraction = loaded.val_fraction
    train_data, val_data = split_chunk_data(demonstrations, loaded.processor, val_fraction)
    policy = loaded.policy
    metadata = policy_metadata(
        policy,
        loaded.processor,
        stage="snapflow",
        teacher=str(loaded.path),
        distill=as_record(settings),
        data={"path": str(data), "val_fraction": val_fraction, "env": demonstrations.env},
        time_distribution=loaded.time_distribution,
    )
    trainable = policy.expert_parameters() if settings.freeze_prefix else None
    return train(
        policy,
        settings.objective(loaded.time_sampler),
        train_data,
        val_data,
        config,
        output,
        metadata,
        resume=resume,
        trainable=trainable,
        progress=progress,
        holder="snapflow distill",
        on_checkpoint=on_checkpoint,
        keep_progress=keep_progress,
        shard=shard,
    )


__all__ = ["policy_config_for", "teacher_objective", "train_teacher", "distill"]
