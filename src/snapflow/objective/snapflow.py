"""The SnapFlow objective (the paper's Algorithm 1), for any :class:`snapflow.protocol.FlowPolicy`.

Each batch is split into a fixed number of flow-matching (FM) samples and consistency samples:

* FM:          L_FM = || F(x_t, s=t, t) - (eps - a) ||^2 with t from the policy's time sampler.
* consistency: v_1 = sg F(x_1, 1, 1); x_.5 = x_1 - v_1 / 2; v_.5 = sg F(x_.5, .5, .5);
               L_SC = || F(x_1, s=0, t=1) - (v_1 + v_.5) / 2 ||^2 with x_1 = eps.

L = alpha * L_FM + (1 - alpha) * lambda * L_SC. The teacher velocities are the model's own marginal
(FM-mode) predictions, not the conditional eps - a, whose variance would bias the jump.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import torch
from torch import Tensor

from snapflow.flow.path import conditional_velocity, euler_step, interpolate
from snapflow.flow.solver import VelocityFn
from snapflow.flow.time_sampling import BetaTimeSampler, TimeSampler
from snapflow.protocol import FlowPolicy, index_batch


@dataclass(frozen=True)
class SnapFlowLossOutput:
    """The total loss (with graph) and its parts (detached, for logging)."""

    loss: Tensor
    flow_matching_loss: Tensor
    consistency_loss: Tensor
    num_flow_matching: int
    num_consistency: int


def two_step_shortcut_target(velocity: VelocityFn, x_1: Tensor, clamp: float | None = None) -> Tensor:
    """Average of the two Euler velocities from t = 1 to 0 along the model's own marginal field.

    Computed without gradient: it is a regression target. ``clamp`` bounds each velocity to +-clamp.
    """
    batch = x_1.shape[0]
    one = torch.ones(batch, device=x_1.device)
    half = torch.full((batch,), 0.5, device=x_1.device)
    with torch.no_grad():
        v_1 = velocity(x_1, one, one)
        if clamp is not None:
            v_1 = v_1.clamp(-clamp, clamp)
        x_half = euler_step(x_1, v_1, one, half)
        v_half = velocity(x_half, half, half)
        if clamp is not None:
            v_half = v_half.clamp(-clamp, clamp)
    return (v_1 + v_half) / 2


@dataclass(frozen=True)
class SnapFlowObjective:
    """SnapFlow progressive self-distillation loss; ``alpha=1`` is plain flow matching (teacher training).

    Args:
        alpha: fraction of each batch routed to the FM branch, and the FM branch's weight.
        consistency_weight: lambda, the consistency branch's weight relative to (1 - alpha).
        time_sampler: the policy's own FM training-time distribution.
        teacher_velocity_clamp: optional bound on the no-grad teacher velocities.
    """

    alpha: float = 0.5
    consistency_weight: float = 0.1
    time_sampler: TimeSampler = field(default_factory=BetaTimeSampler)
    teacher_velocity_clamp: float | None = None

    def __post_init__(self) -> None:
        if not 0.0 <= self.alpha <= 1.0:
            raise ValueError(f"alpha must be in [0, 1], got {self.alpha}")
        if self.consistency_weight < 0:
            raise ValueError(f"consistency_weight (lambda) must be non-negative, got {self.consistency_weight}")
        if self.teacher_velocity_clamp is not None and self.teacher_velocity_clamp <= 0:
            raise ValueError(f"teacher_velocity_clamp must be positive, got {self.teacher_velocity_clamp}")

    def num_flow_matching(self, batch_size: int) -> int:
        """Fixed FM share of a batch: round(alpha * B), keeping both branches present when 0 < alpha < 1."""
        if self.alpha in (0.0, 1.0):
            return int(self.alpha) * batch_size
        if batch_size < 2:
            raise ValueError(f"0 < alpha < 1 needs batches of at least 2 samples to fill both branches, got {batch_size}")
        return min(max(math.floor(self.alpha * batch_size + 0.5), 1), batch_size - 1)

    def __call__(
        self,
        policy: FlowPolicy,
        observation: Any,
        actions: Tensor,
        *,
        noise: Tensor | None = None,
        time: Tensor | None = None,
        generator: torch.Generator | None = None,
    ) -> SnapFlowLossOutput:
        """Loss for one batch of ground-truth ``actions`` (B, ...).

        The first ``num_flow_matching(B)`` samples take the FM branch, the rest the consistency branch.
        ``noise`` (B, ...) and ``time`` (FM samples only) may be given; otherwise they are drawn.
        """
        batch = actions.shape[0]
        n_fm = self.num_flow_matching(batch)
        n_sc = batch - n_fm
        if noise is None:
            noise = torch.randn(actions.shape, device=actions.device, dtype=actions.dtype, generator=generator)
        elif noise.shape != actions.shape:
            raise ValueError(f"noise {tuple(noise.shape)} must match actions {tuple(actions.shape)}")
        if time is None:
            time = self.time_sampler(n_fm, device=actions.device, generator=generator)
        elif time.shape != (n_fm,):
            raise ValueError(f"time must have shape ({n_fm},) for the FM samples, got {tuple(time.shape)}")
        fm_rows, sc_rows = slice(0, n_fm), slice(n_fm, batch)

        context = policy.encode(observation)
        x_1 = noise[sc_rows]
        target = None
        if n_sc:
            sc_context = index_batch(context, sc_rows)
            target = two_step_shortcut_target(
                lambda x, t, s: policy.velocity(x, t, s, sc_context), x_1, self.teacher_velocity_clamp
            )

        # One gradient pass over the whole batch: FM rows at (x_t, s=t, t), consistency rows at (x_1, s=0, t=1).
        ones = torch.ones(n_sc, device=actions.device)
        x_in = torch.cat([interpolate(actions[fm_rows], noise[fm_rows], time), x_1])
        t_in = torch.cat([time.to(ones.dtype), ones])
        s_in = torch.cat([time.to(ones.dtype), torch.zeros_like(ones)])
        prediction = policy.velocity(x_in, t_in, s_in, context)

        zero = prediction.new_zeros(())
        fm_loss = zero
        if n_fm:
            fm_target = conditional_velocity(actions[fm_rows], noise[fm_rows])
            fm_loss = (prediction[fm_rows] - fm_target).pow(2).mean()
        sc_loss = zero
        if n_sc:
            sc_loss = (prediction[sc_rows] - target).pow(2).mean()
        loss = self.alpha * fm_loss + (1 - self.alpha) * self.consistency_weight * sc_loss
        return SnapFlowLossOutput(loss, fm_loss.detach(), sc_loss.detach(), n_fm, n_sc)


__all__ = ["SnapFlowObjective", "SnapFlowLossOutput", "two_step_shortcut_target"]
