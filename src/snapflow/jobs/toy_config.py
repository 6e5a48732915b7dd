"""The toy experiment's settings: plain Python, read by the CLI before torch loads."""

from __future__ import annotations

from dataclasses import dataclass

from snapflow.objective.options import PAPER_ALPHA, PAPER_TARGET_STEPS
from snapflow.training.recipes import DEFAULT_RECIPE, RECIPES


@dataclass(frozen=True)
class ToyConfig:
    """Sizes and schedules of the toy experiment; the defaults run in well under a minute on 2 cores."""

    seed: int = 0
    num_modes: int = 6
    mode_radius: float = 2.0
    teacher_steps: int = 1500
    distill_steps: int = 3000
    batch_size: int = 256
    teacher_lr: float = 2e-3
    distill_lr: float = 1e-3
    alpha: float = PAPER_ALPHA
    consistency_weight: float = RECIPES[DEFAULT_RECIPE].distill_options["consistency_weight"]  # the recipe's lambda
    method: str = "snapflow"  # or a one-step baseline (snapflow.objective.registry.methods())
    target: str = "euler"  # SnapFlow's target and its steps (a list: a schedule), see DistillSettings
    target_steps: int | tuple[int, ...] = PAPER_TARGET_STEPS
    hidden_dim: int = 256
    eval_contexts: int = 12
    samples_per_context: int = 400


__all__ = ["ToyConfig"]
