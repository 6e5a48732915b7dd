"""Sampling modes by name: how many Euler steps, and whether each step asks for a jump (SnapFlow) or the
instantaneous velocity (the teacher; with one step, the naive baseline). Plain Python, read by the CLI before any
torch is loaded."""

from __future__ import annotations

import re
from dataclasses import dataclass

from snapflow.errors import InvalidInputError


@dataclass(frozen=True)
class SamplingMode:
    """How many Euler steps to take and which target time to ask the network for.

    ``jump=False``: s = t at every step (the flow-matching teacher; with one step, the naive baseline).
    ``jump=True``: s = the next grid time, the average-velocity jumps SnapFlow trains for.
    ``num_steps=None`` (``teacher``): the teacher at the policy's own number of steps, which the policy resolves
    (:meth:`with_own_steps`) before it samples.
    """

    num_steps: int | None
    jump: bool

    def __post_init__(self) -> None:
        if self.num_steps is None and self.jump:
            raise InvalidInputError("a jump mode names its number of jumps (snapflow-N)")
        if self.num_steps is not None and self.num_steps < 1:
            raise InvalidInputError(f"num_steps must be at least 1, got {self.num_steps}")

    @property
    def resolved(self) -> bool:
        """Whether it names its number of steps (every mode but the bare ``teacher``)."""
        return self.num_steps is not None

    def with_own_steps(self, own_steps: int) -> SamplingMode:
        """This mode with a policy's own number of steps ``own_steps`` where it asks for them (``teacher``)."""
        return self if self.resolved else SamplingMode(own_steps, jump=False)

    @property
    def name(self) -> str:
        """Canonical name, accepted back by :meth:`parse`."""
        if not self.resolved:
            return "teacher"
        if self.jump:
            return f"snapflow-{self.num_steps}"
        return "naive-1" if self.num_steps == 1 else f"teacher-{self.num_steps}"

    def __str__(self) -> str:
        return self.name

    @property
    def description(self) -> str:
        """What this mode computes, in one line for a report."""
        if not self.resolved:
            return "the flow-matching sampler at the policy's own number of Euler steps"
        if self.jump:
            if self.num_steps == 1:
                return "one jump from noise to actions with the distilled average velocity F(x_1, s=0, t=1)"
            return f"{self.num_steps} jumps along the time grid with the distilled average velocity"
        if self.num_steps == 1:
            return (
                "one Euler step of the instantaneous velocity (s = t = 1), without distillation: "
                "the baseline a one-step method must beat"
            )
        return f"{self.num_steps} Euler steps of the instantaneous velocity (s = t): the flow-matching sampler"

    @classmethod
    def parse(cls, name: str) -> SamplingMode:
        """Read ``teacher-N``, ``snapflow-N``, ``naive`` / ``naive-1``; bare ``teacher`` is the policy's own number of
        steps, bare ``snapflow`` one jump.

        Raises:
            InvalidInputError: an unknown name, ``naive`` with more than one step, or no step at all.

        Examples:
            >>> from snapflow import SamplingMode
            >>> SamplingMode.parse("teacher-10")
            SamplingMode(num_steps=10, jump=False)
            >>> SamplingMode.parse("snapflow").name
            'snapflow-1'
            >>> SamplingMode.parse("teacher").with_own_steps(5).name  # a policy's own
            'teacher-5'
        """
        match = re.fullmatch(r"(teacher|snapflow|naive)(?:-(\d+))?", name.strip().lower())
        if match is None:
            raise InvalidInputError(
                f"unknown sampling mode {name!r}; use teacher-N, snapflow-N or naive (e.g. teacher-10, snapflow-1)"
            )
        kind, steps = match.group(1), match.group(2)
        if kind == "naive":
            if steps not in (None, "1"):
                raise InvalidInputError(f"naive sampling is one step by definition, got {name!r}")
            return cls(1, jump=False)
        if steps is not None and int(steps) < 1:
            raise InvalidInputError(f"sampling mode {name!r} takes no step; a mode needs at least one")
        if kind == "teacher":
            return cls(int(steps) if steps else None, jump=False)
        return cls(int(steps) if steps else 1, jump=True)


TEACHER_10 = SamplingMode(10, jump=False)
"""The flow-matching teacher's own sampler: ten Euler steps of the instantaneous velocity."""
NAIVE_1 = SamplingMode(1, jump=False)
"""One Euler step of the instantaneous velocity, undistilled: the baseline a one-step method must beat."""
SNAPFLOW_1 = SamplingMode(1, jump=True)
"""SnapFlow's one jump from noise to actions with the distilled average velocity."""
# what a comparison of a teacher and its student samples by default: the teacher, the naive step, the student's jump
STANDARD_MODES: tuple[SamplingMode, ...] = (TEACHER_10, NAIVE_1, SNAPFLOW_1)


__all__ = ["SamplingMode", "TEACHER_10", "NAIVE_1", "SNAPFLOW_1", "STANDARD_MODES"]
