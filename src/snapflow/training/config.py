"""Training settings and the built-in recipes' defaults, in one place: plain Python that the CLI reads before any
torch is loaded."""

from __future__ import annotations

import math
from dataclasses import dataclass

from snapflow.errors import InvalidInputError
from snapflow.reporting.records import added_option


@dataclass(frozen=True)
class TrainConfig:
    """One training run's optimisation settings: AdamW with linear warm-up and cosine decay, gradient clipping,
    periodic validation and checkpoints.

    ``ema_decay``: keep an exponential moving average of the trained weights (see
    :class:`snapflow.training.ema.WeightAverage`) and save it as each checkpoint's policy, the raw weights beside it
    for resuming; None trains and saves the raw weights only.
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

    def __post_init__(self) -> None:
        for name in ("steps", "batch_size", "log_every", "validate_every", "checkpoint_every", "keep_checkpoints"):
            if getattr(self, name) < 1:
                raise InvalidInputError(f"TrainConfig.{name} must be at least 1, got {getattr(self, name)}")
        if self.learning_rate <= 0:
            raise InvalidInputError(f"TrainConfig.learning_rate must be positive, got {self.learning_rate}")
        if self.ema_decay is not None and not 0 < self.ema_decay < 1:
            raise InvalidInputError(f"TrainConfig.ema_decay must be between 0 and 1 (exclusive), got {self.ema_decay}")

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
