"""The SnapFlow objective (the paper's Algorithm 1), for any :class:`snapflow.protocol.FlowPolicy`.

Each batch is split into a fixed number of flow-matching (FM) samples and consistency samples:

* FM:          L_FM = || F(x_t, s=t, t) - (eps - a) ||^2 with t from the policy's time sampler.
* consistency: v_1 = sg F(x_1, 1, 1); x_.5 = x_1 - v_1 / 2; v_.5 = sg F(x_.5, .5, .5);
               L_SC = || F(x_1, s=0, t=1) - (v_1 + v_.5) / 2 ||^2 with x_1 = eps.

L = alpha * L_FM + (1 - alpha) * lambda * L_SC. The teacher velocities are the model's own marginal
(FM-mode) predictions, not the conditional eps - a, whose variance would bias the jump
(``teacher_velocity="conditional"`` is that ablation, the paper's Table 5).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Literal

import torch
from torch import Tensor

from snapflow.flow.path import conditional_velocity, euler_step
from snapflow.flow.solver import VelocityFn
from snapflow.flow.time_sampling import BetaTimeSampler, TimeSampler
from snapflow.objective.base import OneStepRows, TwoBranchObjective
from snapflow.protocol import Context, FlowPolicy

TEACHER_VELOCITIES = ("marginal", "conditional")


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
class SnapFlowObjective(TwoBranchObjective):
    """SnapFlow progressive self-distillation loss; ``alpha=1`` is plain flow matching (teacher training).

    Args:
        alpha: fraction of each batch routed to the FM branch, and the FM branch's weight.
        consistency_weight: lambda, the consistency branch's weight relative to (1 - alpha).
        time_sampler: the policy's own FM training-time distribution.
        teacher_velocity_clamp: optional bound on the no-grad teacher velocities.
        teacher_velocity: ``"marginal"`` (the model's own FM velocities, the paper's method) or
            ``"conditional"`` (eps - a on the straight path, the ablation the paper's theory says drifts:
            its two-step average is eps - a again, so the jump regresses the conditional mean of the actions).
    """

    alpha: float = 0.5
    consistency_weight: float = 0.1
    time_sampler: TimeSampler = field(default_factory=BetaTimeSampler)
    teacher_velocity_clamp: float | None = None
    teacher_velocity: Literal["marginal", "conditional"] = "marginal"

    def __post_init__(self) -> None:
        self._check_weights()
        if self.teacher_velocity_clamp is not None and self.teacher_velocity_clamp <= 0:
            raise ValueError(f"teacher_velocity_clamp must be positive, got {self.teacher_velocity_clamp}")
        if self.teacher_velocity not in TEACHER_VELOCITIES:
            raise ValueError(f"teacher_velocity must be one of {TEACHER_VELOCITIES}, got {self.teacher_velocity!r}")

    def one_step_rows(
        self, policy: FlowPolicy, observation: Any, context: Context, actions: Tensor, noise: Tensor,
        generator: torch.Generator | None,
    ) -> OneStepRows:
        """The jump t = 1 -> s = 0 from x_1 = eps onto the two-step shortcut of the teacher velocities."""
        if self.teacher_velocity == "conditional":
            target = conditional_velocity(actions, noise)
        else:
            target = two_step_shortcut_target(lambda x, t, s: policy.velocity(x, t, s, context), noise, self.teacher_velocity_clamp)
        ones = torch.ones(noise.shape[0], device=noise.device)
        return OneStepRows(noise, ones, torch.zeros_like(ones), target)


__all__ = ["SnapFlowObjective", "TEACHER_VELOCITIES", "two_step_shortcut_target"]
