"""Training settings and the built-in recipes' defaults, in one place: plain Python that the CLI reads before any
torch is loaded."""

from __future__ import annotations

import math
from dataclasses import dataclass

from snapflow.errors import InvalidInputError
from snapflow.flow.time_distribution import UNIFORM, canonical_time_distribution
from snapflow.reporting.records import added_option


@dataclass(frozen=True)
class TrainConfig:
    """One training run's optimisation settings: AdamW with linear warm-up and cosine decay, gradient clipping,
    periodic validation and checkpoints.

    Args:
        steps: optimiser steps of the whole run.
        batch_size: the training pairs of one optimisation step, over all the processes of an ``accelerate
            launch`` (each trains on ``batch_size / processes`` of them; see :mod:`snapflow.training.trainer`), so a
            run's settings mean the same run on one process or several.
        learning_rate: the peak learning rate, reached after the warm-up.
        warmup_steps: steps of the linear warm-up from ``learning_rate / warmup_steps``.
        min_learning_rate_ratio: where the cosine decay ends, as a share of ``learning_rate`` (1: constant).
        weight_decay: AdamW's.
        grad_clip: the gradients' norm is clipped to this (0: no clipping).
        seed: seeds step k's global batch with (seed, k), the same on every process, so a resumed run continues the
            same curve on any number of processes (see :mod:`snapflow.training.trainer`).
        log_every: steps between two rows of the loss history.
        validate_every: steps between two validation losses (and at the last step).
        checkpoint_every: steps between two checkpoints (and at the last step).
        keep_checkpoints: how many of the newest checkpoints a run keeps.
        mixed_precision: Accelerate's ``"no"``, ``"bf16"`` or ``"fp16"``.
        ema_decay: keep an exponential moving average of the trained weights (see
            :class:`snapflow.training.ema.WeightAverage`) and save it as each checkpoint's policy, the raw weights
            beside it for resuming; None trains and saves the raw weights only.
        time_distribution: a teacher's flow-matching times, one of
            :data:`~snapflow.flow.time_distribution.TIME_DISTRIBUTIONS` (``uniform``, ``beta:1.5``, ``shift:4``),
            written one way (``beta:1.50`` is kept as ``beta:1.5``). A built-in teacher's setting, recorded in its
            checkpoint; a student's flow-matching rows draw its teacher's (shifted by its
            :class:`~snapflow.objective.settings.DistillSettings` ``time_shift``), so a student's training keeps the
            default (:meth:`check_student`).

    Examples:
        >>> from snapflow.training.config import TrainConfig
        >>> config = TrainConfig(steps=1000, learning_rate=1e-3, warmup_steps=100)
        >>> config.learning_rate_at(0), config.learning_rate_at(99)  # the warm-up
        (1e-05, 0.001)
        >>> round(config.learning_rate_at(999), 6)  # decayed to 0.1 of the peak
        0.0001
    """

    steps: int = 3000
    batch_size: int = 64
    learning_rate: float = 3e-4
    warmup_steps: int = 100
    min_learning_rate_ratio: float = 0.1
    weight_decay: float = 0.0
    grad_clip: float = 1.0
    seed: int = 0
    log_every: int = 50
    validate_every: int = 500
    checkpoint_every: int = 500
    keep_checkpoints: int = 2
    mixed_precision: str = "no"
    ema_decay: float | None = added_option(None)
    time_distribution: str = added_option(UNIFORM)

    def __post_init__(self) -> None:
        for name in ("steps", "batch_size", "log_every", "validate_every", "checkpoint_every", "keep_checkpoints"):
            if getattr(self, name) < 1:
                raise InvalidInputError(f"TrainConfig.{name} must be at least 1, got {getattr(self, name)}")
        if self.learning_rate <= 0:
            raise InvalidInputError(f"TrainConfig.learning_rate must be positive, got {self.learning_rate}")
        if self.ema_decay is not None and not 0 < self.ema_decay < 1:
            raise InvalidInputError(f"TrainConfig.ema_decay must be between 0 and 1 (exclusive), got {self.ema_decay}")
        try:
            object.__setattr__(self, "time_distribution", canonical_time_distribution(self.time_distribution))
        except InvalidInputError as error:
            raise InvalidInputError(f"TrainConfig.time_distribution: {error}") from None

    def check_student(self, where: str) -> None:
        """Refuse a time distribution of a student's training (named by ``where``): its flow-matching rows draw its
        teacher's times, which the teacher's checkpoint records."""
        if self.time_distribution != UNIFORM:
            raise InvalidInputError(
                f"{where}: time_distribution {self.time_distribution!r} is a teacher's setting: a student's "
                "flow-matching rows draw its teacher's times (shift them with the distillation's time_shift)"
            )

    def learning_rate_at(self, step: int) -> float:
        """Linear warm-up, then cosine decay to ``min_learning_rate_ratio`` of the peak."""
        if step < self.warmup_steps:
            return self.learning_rate * (step + 1) / self.warmup_steps
        progress = (step - self.warmup_steps) / max(self.steps - self.warmup_steps, 1)
        floor = self.min_learning_rate_ratio
        return self.learning_rate * (floor + (1 - floor) * 0.5 * (1 + math.cos(math.pi * min(progress, 1.0))))


VAL_FRACTION = 0.1  # share of each task's demonstration episodes held out for validation and offline metrics
# A converged teacher matters (the paper: distilling an under-trained one distills noise); the paper's student
# starts at the teacher's final learning rate (3e-5, near the paper's 2.5e-5) so it stays in its basin. The
# student's recipes (the paper's and snapflow's own) are in snapflow.training.recipes.RECIPES.
TEACHER_TRAINING = TrainConfig(steps=5000, learning_rate=3e-4)
PAPER_STUDENT_TRAINING = TrainConfig(steps=2000, learning_rate=3e-5, warmup_steps=50)


def paper_training() -> TrainConfig:
    """The paper's settings of a LeRobot student: AdamW at 2.5e-5 after 500 warm-up steps, batch 4, ~30k steps, bf16
    where the GPU has it (asked of the machine when called, not at import: torch loads then)."""
    import torch

    return TrainConfig(
        steps=30000,
        batch_size=4,
        learning_rate=2.5e-5,
        warmup_steps=500,
        min_learning_rate_ratio=1.0,
        checkpoint_every=1000,
        mixed_precision="bf16" if torch.cuda.is_available() and torch.cuda.is_bf16_supported() else "no",
    )


__all__ = ["TrainConfig", "VAL_FRACTION", "TEACHER_TRAINING", "PAPER_STUDENT_TRAINING", "paper_training"]
