"""Consistency distillation (Song et al., 2023) in the SnapFlow harness: a one-step baseline.

The consistency function is read off the target-time branch as f(x_t, t) = x_t - t * F(x_t, t, s=0), so
f(x, 0) = x holds by construction and 1-NFE sampling is the same jump as SnapFlow's. For a random pair
of neighbours t_lo = (n - 1) / N < t_hi = n / N on an N-interval grid:

    x_hi = (1 - t_hi) a + t_hi eps;   x_lo = x_hi - (t_hi - t_lo) sg F(x_hi, t_hi, t_hi)   (one teacher Euler step)
    L_CD = || f_theta(x_hi, t_hi) - f_ema(x_lo, t_lo) ||^2 = t_hi^2 || F_theta(x_hi, t_hi, 0) - (x_hi - f_ema) / t_hi ||^2,

where f_ema uses an exponential moving average of the weights (the "target network"). As in SnapFlow, the
teacher velocity is the model's own FM velocity, which the FM rows keep trained; the original method
uses a separate frozen teacher network.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, field
from typing import Any, ClassVar

import torch
from torch import Tensor, nn

from snapflow.errors import InvalidInputError
from snapflow.flow.path import broadcast_time, euler_step, interpolate
from snapflow.flow.time_sampling import BetaTimeSampler, TimeSampler
from snapflow.objective.base import OneStepRows, TwoBranchObjective, uniform
from snapflow.objective.options import PAPER_ALPHA, PAPER_CONSISTENCY_WEIGHT
from snapflow.protocol import Context, FlowPolicy


@dataclass
class ConsistencyDistillationObjective(TwoBranchObjective):
    """Consistency distillation with an EMA target network.

    Args:
        alpha, consistency_weight, time_sampler: as for :class:`snapflow.objective.SnapFlowObjective`.
        num_intervals: N, the number of teacher Euler steps the grid from t = 1 to 0 is cut into.
        ema_decay: decay of the target network's moving average (Song et al. use 0.95 with a fixed N).

    The target network is copied from the policy at the first call and moved towards it at the start of
    every later call made in training mode (validation, in eval mode, leaves it alone). It is not part of
    the policy's checkpoint: a resumed run restarts it from the resumed weights.
    """

    alpha: float = PAPER_ALPHA
    consistency_weight: float = PAPER_CONSISTENCY_WEIGHT
    time_sampler: TimeSampler = field(default_factory=BetaTimeSampler)
    num_intervals: int = 10
    ema_decay: float = 0.95
    _target: nn.Module | None = field(default=None, init=False, repr=False, compare=False)
    copies_policy: ClassVar[bool] = True  # its target network

    def __post_init__(self) -> None:
        self._check_weights()
        if self.num_intervals < 1:
            raise InvalidInputError(f"num_intervals must be at least 1, got {self.num_intervals}")
        if not 0.0 <= self.ema_decay < 1.0:
            raise InvalidInputError(f"ema_decay must be in [0, 1), got {self.ema_decay}")

    @torch.no_grad()
    def _target_network(self, policy: FlowPolicy) -> nn.Module:
        if self._target is None:
            self._target = copy.deepcopy(policy).requires_grad_(False)
        elif policy.training:
            for target, online in zip(self._target.parameters(), policy.parameters(), strict=True):
                target.lerp_(online, 1.0 - self.ema_decay)
        return self._target.train(policy.training)

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
        target_network = self._target_network(policy)
        rows = noise.shape[0]
        interval = (uniform(rows, generator, noise) * self.num_intervals).floor().clamp(max=self.num_intervals - 1)
        t_hi, t_lo = (interval + 1) / self.num_intervals, interval / self.num_intervals
        x_hi = interpolate(actions, noise, t_hi)
        with torch.no_grad():
            x_lo = euler_step(x_hi, policy.velocity(x_hi, t_hi, t_hi, context), t_hi, t_lo)
            target_context = target_network.encode(observation)
            consistent = x_lo - broadcast_time(t_lo, x_lo) * target_network.velocity(
                x_lo, t_lo, torch.zeros_like(t_lo), target_context
            )
            target = (x_hi - consistent) / broadcast_time(t_hi, x_hi)
        return OneStepRows(x_hi, t_hi, torch.zeros_like(t_hi), target, weight=t_hi.pow(2))


__all__ = ["ConsistencyDistillationObjective"]
