"""Objective options as plain Python (no torch), so the settings layer and the CLI can name and check them before
any model is built."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Literal, get_args

# where SnapFlow's consistency target comes from: the model's marginal velocity (the paper), or eps - a (ablation)
TeacherVelocity = Literal["marginal", "conditional"]
TEACHER_VELOCITIES: tuple[str, ...] = get_args(TeacherVelocity)

# The paper's SnapFlow settings, written once: every objective, DistillSettings, the toy experiment and the LeRobot
# student config default to them, and help texts quote them.
# alpha: the share of each batch kept on flow matching, and that branch's weight
PAPER_ALPHA = 0.5
# lambda: the consistency branch's weight relative to (1 - alpha)
PAPER_CONSISTENCY_WEIGHT = 0.1
# K: the Euler steps the one-step target averages (two: the two-step Euler target)
PAPER_TARGET_STEPS = 2


def target_stages(target_steps: int | Sequence[int]) -> tuple[int, ...]:
    """``target_steps`` as a schedule: one stage for a fixed K."""
    return (target_steps,) if isinstance(target_steps, int) else tuple(target_steps)


__all__ = [
    "PAPER_ALPHA",
    "PAPER_CONSISTENCY_WEIGHT",
    "PAPER_TARGET_STEPS",
    "TeacherVelocity",
    "TEACHER_VELOCITIES",
    "target_stages",
]
