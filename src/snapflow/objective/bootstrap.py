"""SnapFlow with a bootstrapped shortcut target, in the spirit of shortcut models (Frans et al., 2024).

Jumps of every size h = 1, 1/2, ..., 2/K are trained together, each from a grid time t (a multiple of h) to
s = t - h, starting at x_t on the straight path (x_1 = eps, as for the one-step jump). Its target is the
model's own two half-jumps through m = t - h/2, computed without gradient:

    u_1 = sg F(x_t, t, m);  x_m = x_t - (h/2) u_1;  u_2 = sg F(x_m, m, s);  target = (u_1 + u_2) / 2.

The smallest jumps, h = 2/K, take the instantaneous FM velocities instead (F(x_t, t, t) and F(x_m, m, m)),
so that level is SnapFlow's two-step target on an interval of length h. Once the smaller jumps have been
learnt, the one-step jump 1 -> 0 regresses a K-step Euler solution of the teacher, yet every row costs three
passes (two no-grad, one with gradient) whatever K is: ``target_steps=2`` is exactly SnapFlow.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import torch
from torch import Tensor

from snapflow.errors import InvalidInputError
from snapflow.flow.path import euler_step, interpolate
from snapflow.flow.time_sampling import BetaTimeSampler, TimeSampler
from snapflow.objective.base import OneStepRows, TwoBranchObjective, uniform
from snapflow.objective.options import PAPER_ALPHA, PAPER_CONSISTENCY_WEIGHT
from snapflow.protocol import Context, FlowPolicy


@dataclass(frozen=True)
class BootstrappedSnapFlowObjective(TwoBranchObjective):
    """SnapFlow whose one-step target is bootstrapped from the model's own shorter jumps.

    Args:
        alpha, consistency_weight, time_sampler: as for :class:`snapflow.objective.SnapFlowObjective`.
        target_steps: K, a power of two: the Euler steps the one-step target reaches once the levels have
            converged (log2 K jump sizes, one-step rows drawn evenly over them).
    """

    alpha: float = PAPER_ALPHA
    consistency_weight: float = PAPER_CONSISTENCY_WEIGHT
    time_sampler: TimeSampler = field(default_factory=BetaTimeSampler)
    target_steps: int = 8

    def __post_init__(self) -> None:
        self._check_weights()
        if isinstance(self.target_steps, tuple | list):
            raise InvalidInputError(
                "a bootstrapped target grows by itself from 2 to target_steps Euler steps; give target_steps one power "
                f"of two, not the schedule {list(self.target_steps)}"
            )
        if (
            not isinstance(self.target_steps, int)
            or self.target_steps < 2
            or self.target_steps & (self.target_steps - 1)
        ):
            raise InvalidInputError(
                f"a bootstrapped target needs target_steps a power of two >= 2, got {self.target_steps!r}"
            )

    @property
    def levels(self) -> int:
        """Number of jump sizes trained: 1, 1/2, ..., 2 / target_steps."""
        return int(math.log2(self.target_steps))

    def one_step_rows(
        self,
        policy: FlowPolicy,
        observation: Any,
        context: Context,
        actions: Tensor,
        noise: Tensor,
        generator: torch.Generator | None,
        progress: float,
    ) -> OneStepRows:
        rows = noise.shape[0]
        level = (uniform(rows, generator, noise) * self.levels).floor().clamp(max=self.levels - 1)
        jumps_at_level = torch.exp2(level)
        h = 1.0 / jumps_at_level
        t = ((uniform(rows, generator, noise) * jumps_at_level).floor().clamp(max=jumps_at_level - 1) + 1) * h
        s, m = t - h, t - h / 2
        finest = level == self.levels - 1
        x_t = interpolate(actions, noise, t)
        with torch.no_grad():
            first = policy.velocity(x_t, t, torch.where(finest, t, m), context)
            x_m = euler_step(x_t, first, t, m)
            second = policy.velocity(x_m, m, torch.where(finest, m, s), context)
        return OneStepRows(x_t, t, s, (first + second) / 2)


__all__ = ["BootstrappedSnapFlowObjective"]
