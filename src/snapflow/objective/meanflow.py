"""MeanFlow (Geng et al., 2025) in the SnapFlow harness: a one-step baseline.

F(x_t, t, s) is read as the average velocity u of the jump t -> s, which obeys the MeanFlow identity
(with this library's convention, t = 1 noise, s < t):

    u(x_t, t, s) = v(x_t, t) - (t - s) * d/dt u(x_t, t, s),   d/dt = v . d/dx + d/dt   (s held fixed).

The one-step rows draw s < t uniformly, put x_t on the straight path and regress F(x_t, t, s) on the
right-hand side without gradient; the total derivative is one forward-mode JVP. As in SnapFlow, v is the
model's own FM velocity F(x_t, t, t) (the original trains from scratch on eps - a); the FM rows keep it
trained.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import torch
from torch import Tensor
from torch.nn.attention import SDPBackend, sdpa_kernel

from snapflow.errors import InvalidInputError
from snapflow.flow.path import broadcast_time, interpolate
from snapflow.flow.time_sampling import BetaTimeSampler, TimeSampler
from snapflow.objective.base import OneStepRows, TwoBranchObjective, uniform
from snapflow.objective.options import PAPER_ALPHA, PAPER_CONSISTENCY_WEIGHT
from snapflow.protocol import Context, FlowPolicy


@dataclass(frozen=True)
class MeanFlowObjective(TwoBranchObjective):
    """MeanFlow-style average-velocity distillation.

    Args:
        alpha, consistency_weight, time_sampler: as for :class:`snapflow.objective.SnapFlowObjective`.
        adaptive_power: p of MeanFlow's adaptive loss weighting (its best setting, 1.0). Without it the
            bootstrapped target feeds on its own errors: d/dt u through high-frequency time features is
            large, and on a small policy the loss was measured to grow 8000-fold in 300 steps.
    """

    alpha: float = PAPER_ALPHA
    consistency_weight: float = PAPER_CONSISTENCY_WEIGHT
    time_sampler: TimeSampler = field(default_factory=BetaTimeSampler)
    adaptive_power: float = 1.0

    def __post_init__(self) -> None:
        self._check_weights()
        if self.adaptive_power < 0:
            raise InvalidInputError(f"adaptive_power must be non-negative, got {self.adaptive_power}")

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
        first, second = uniform(rows, generator, noise), uniform(rows, generator, noise)
        t, s = torch.maximum(first, second), torch.minimum(first, second)
        x_t = interpolate(actions, noise, t)
        with torch.no_grad():
            velocity = policy.velocity(x_t, t, t, context)
        # Fused attention kernels have no forward-mode derivative; the reference (math) kernel does.
        with torch.no_grad(), sdpa_kernel(SDPBackend.MATH):
            _, total_derivative = torch.func.jvp(
                lambda x, time: policy.velocity(x, time, s, context), (x_t, t), (velocity, torch.ones_like(t))
            )
            target = velocity - broadcast_time(t - s, x_t) * total_derivative
        return OneStepRows(x_t, t, s, target, adaptive_power=self.adaptive_power)


__all__ = ["MeanFlowObjective"]
