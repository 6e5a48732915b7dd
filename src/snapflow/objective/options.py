"""Objective options as plain Python (no torch), so the settings layer and the CLI can name and check them before
any model is built."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Literal, get_args

# where SnapFlow's consistency target comes from: the model's marginal velocity (the paper), or eps - a (ablation)
TeacherVelocity = Literal["marginal", "conditional"]
TEACHER_VELOCITIES: tuple[str, ...] = get_args(TeacherVelocity)


def target_stages(target_steps: int | Sequence[int]) -> tuple[int, ...]:
    """``target_steps`` as a schedule: one stage for a fixed K."""
    return (target_steps,) if isinstance(target_steps, int) else tuple(target_steps)


__all__ = ["TeacherVelocity", "TEACHER_VELOCITIES", "target_stages"]
