"""The SnapFlow objective (the paper's Algorithm 1), for any :class:`snapflow.protocol.FlowPolicy`.

Each batch is split into a fixed number of flow-matching (FM) samples and consistency samples:

* FM:          L_FM = || F(x_t, s=t, t) - (eps - a) ||^2 with t from the policy's time sampler.
* consistency: v_1 = sg F(x_1, 1, 1); x_.5 = x_1 - v_1 / 2; v_.5 = sg F(x_.5, .5, .5);
               L_SC = || F(x_1, s=0, t=1) - (v_1 + v_.5) / 2 ||^2 with x_1 = eps.

L = alpha * L_FM + (1 - alpha) * lambda * L_SC. The teacher velocities are the model's own marginal
(FM-mode) predictions, not the conditional eps - a, whose variance would bias the jump
(``teacher_velocity="conditional"`` is that ablation, the paper's Table 5).

Beyond the paper, the shortcut target may average K > 2 Euler velocities (``target_steps``), fixed or raised
in stages over training: two Euler steps of a multimodal field blur its modes, and the one-step student
inherits the blur; more steps cost one more no-grad pass each.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import torch
from torch import Tensor

from snapflow.errors import InvalidInputError
from snapflow.flow.modes import SamplingMode
from snapflow.flow.path import conditional_velocity, euler_step, interpolate
from snapflow.flow.solver import VelocityFn, euler_sample
from snapflow.flow.time_sampling import BetaTimeSampler, TimeSampler
from snapflow.objective.base import OneStepRows, TwoBranchObjective, uniform
from snapflow.objective.options import (
    PAPER_ALPHA,
    PAPER_CONSISTENCY_WEIGHT,
    PAPER_TARGET_STEPS,
    TEACHER_VELOCITIES,
    TeacherVelocity,
    target_stages,
)
from snapflow.protocol import Context, FlowPolicy


def euler_shortcut_target(
    velocity: VelocityFn, x_1: Tensor, steps: int = PAPER_TARGET_STEPS, clamp: float | None = None
) -> Tensor:
    """Average of the ``steps`` Euler velocities from t = 1 to 0 along the model's own marginal field,
    i.e. x_1 - x_0 for the K-step Euler solution x_0 (uniform steps); the default ``steps`` is the paper's target.

    Computed without gradient: it is a regression target. ``clamp`` bounds each velocity to +-clamp.
    """
    teacher = velocity if clamp is None else (lambda x, t, s: velocity(x, t, s).clamp(-clamp, clamp))
    with torch.no_grad():
        return x_1 - euler_sample(teacher, x_1, SamplingMode(steps, jump=False))


def jump_target(
    velocity: VelocityFn,
    x_t: Tensor,
    t: Tensor,
    s: Tensor,
    steps: int = PAPER_TARGET_STEPS,
    clamp: float | None = None,
) -> Tensor:
    """Average of the ``steps`` Euler velocities of the model's own marginal field from time ``t`` down to ``s``
    (per row): the average velocity of the jump t -> s that the K-step Euler solver takes. At (t, s) = (1, 0) it is
    :func:`euler_shortcut_target`. Computed without gradient; ``clamp`` bounds each velocity to +-clamp."""
    teacher = velocity if clamp is None else (lambda x, time, _: velocity(x, time, time).clamp(-clamp, clamp))
    with torch.no_grad():
        x, total = x_t, torch.zeros_like(x_t)
        for k in range(steps):
            time, next_time = t - (t - s) * k / steps, t - (t - s) * (k + 1) / steps
            v = teacher(x, time, time)
            total = total + v
            x = euler_step(x, v, time, next_time)
        return total / steps


def stage_at(stages: Sequence[int], progress: float) -> int:
    """The stage in force at ``progress`` (fraction of training done) when ``stages`` split training equally."""
    return stages[min(max(int(progress * len(stages)), 0), len(stages) - 1)]


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
            its K-step average is eps - a again, so the jump regresses the conditional mean of the actions).
        target_steps: K, the Euler steps the target averages (2: the paper), or a schedule of K that
            splits training into equal stages, e.g. ``(2, 4, 8)``; each step costs one no-grad pass.
        intermediate_jumps: share of the one-step rows that jump between two inner times instead of 1 -> 0:
            t ~ U(0, 1), s ~ U(0, t), from x_t on the path between the demonstration and its noise, onto the K-step
            Euler average of the teacher velocities from t to s (0: the paper, every row jumps from pure noise).

    Examples:
        One batch of a tiny MLP student: half its rows train flow matching, half the one-step jump.

        >>> import torch
        >>> from snapflow import SnapFlowObjective, SnapFlowPolicy, UniformTimeSampler
        >>> from snapflow.policies.mlp import MLPFlowModel, MLPPolicyConfig
        >>> config = MLPPolicyConfig(
        ...     observation_dim=4, action_dim=2, chunk_length=3, hidden_dim=32
        ... )
        >>> student = SnapFlowPolicy(MLPFlowModel(config))
        >>> objective = SnapFlowObjective(alpha=0.5, time_sampler=UniformTimeSampler())
        >>> observation, actions = torch.randn(8, 4), torch.randn(8, 3, 2)  # 8 chunks
        >>> output = objective(student, observation, actions)
        >>> output.num_flow_matching, output.num_consistency
        (4, 4)
        >>> output.loss.backward()  # then an optimiser's step, as train() takes it
    """

    alpha: float = PAPER_ALPHA
    consistency_weight: float = PAPER_CONSISTENCY_WEIGHT
    time_sampler: TimeSampler = field(default_factory=BetaTimeSampler)
    teacher_velocity_clamp: float | None = None
    teacher_velocity: TeacherVelocity = "marginal"
    target_steps: int | tuple[int, ...] = PAPER_TARGET_STEPS
    intermediate_jumps: float = 0.0

    def __post_init__(self) -> None:
        self._check_weights()
        if not 0 <= self.intermediate_jumps <= 1:
            raise InvalidInputError(f"intermediate_jumps must be in [0, 1], got {self.intermediate_jumps}")
        if self.teacher_velocity_clamp is not None and self.teacher_velocity_clamp <= 0:
            raise InvalidInputError(f"teacher_velocity_clamp must be positive, got {self.teacher_velocity_clamp}")
        if self.teacher_velocity not in TEACHER_VELOCITIES:
            raise InvalidInputError(
                f"teacher_velocity must be one of {TEACHER_VELOCITIES}, got {self.teacher_velocity!r}"
            )
        stages = target_stages(self.target_steps)
        if not stages or not all(isinstance(k, int) and k >= 1 for k in stages):
            raise InvalidInputError(
                f"target_steps must be a positive integer or a non-empty list of them, got {self.target_steps!r}"
            )
        object.__setattr__(self, "target_steps", stages[0] if len(stages) == 1 else stages)

    def schedule(self, progress: float) -> dict[str, int]:
        """K in force at ``progress``, logged by the trainer."""
        return {"target_steps": stage_at(target_stages(self.target_steps), progress)}

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
        """The jump t = 1 -> s = 0 from x_1 = eps onto the K-step Euler shortcut of the teacher velocities; the
        first ``intermediate_jumps`` share of the rows jump between inner times instead. At lambda 0 the rows have no
        target and cost no teacher pass (a subclass may still score them, as the energy term does)."""
        rows = noise.shape[0]
        inner = round(self.intermediate_jumps * rows)
        t = torch.ones(rows, device=noise.device)
        s = torch.zeros_like(t)
        x = noise
        if inner:
            t_inner = 1 - uniform(inner, generator, t)  # in (0, 1]
            s_inner = t_inner * uniform(inner, generator, t)
            t, s = torch.cat([t_inner, t[inner:]]), torch.cat([s_inner, s[inner:]])
            x = torch.cat([interpolate(actions[:inner], noise[:inner], t_inner), noise[inner:]])
        if self.consistency_weight == 0:  # a term weighted 0 costs nothing: no target, no teacher pass
            return OneStepRows(x, t, s, None)
        if self.teacher_velocity == "conditional":  # the straight path's average velocity over any jump
            return OneStepRows(x, t, s, conditional_velocity(actions, noise))
        steps = self.schedule(progress)["target_steps"]
        velocity = lambda x, t, s: policy.velocity(x, t, s, context)  # noqa: E731
        if inner:  # per-row times; the 1 -> 0 rows get the paper's target up to rounding
            return OneStepRows(x, t, s, jump_target(velocity, x, t, s, steps, self.teacher_velocity_clamp))
        return OneStepRows(x, t, s, euler_shortcut_target(velocity, noise, steps, self.teacher_velocity_clamp))


__all__ = [
    "SnapFlowObjective",
    "euler_shortcut_target",
    "jump_target",
    "stage_at",
]
