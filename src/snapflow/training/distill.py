"""Settings of a distillation run, shared by every policy family."""

from __future__ import annotations

from dataclasses import dataclass

from snapflow.flow.time_sampling import BetaTimeSampler, TimeSampler
from snapflow.objective import (
    BootstrappedSnapFlowObjective,
    ConsistencyDistillationObjective,
    MeanFlowObjective,
    SnapFlowObjective,
    TwoBranchObjective,
)
from snapflow.objective.snapflow import TEACHER_VELOCITIES

METHODS = ("snapflow", "consistency-distillation", "meanflow")
TARGETS = ("euler", "bootstrap")


@dataclass(frozen=True)
class DistillSettings:
    """The paper's defaults: SnapFlow, alpha 0.5, lambda 0.1, no clamp, prefix (VLM) frozen, phi_s attached,
    two-step Euler target.

    ``method`` picks the one-step objective (the baselines share alpha and lambda); ``teacher_velocity``
    and ``target_time`` exist for the paper's ablations (conditional velocity; no target-time embedding).
    SnapFlow's target is ``target="euler"`` (the average of ``target_steps`` Euler velocities; a list of
    them is a schedule over equal stages of training) or ``target="bootstrap"`` (built from the model's own
    half-jumps, reaching ``target_steps`` Euler steps at three passes per row; see
    :mod:`snapflow.objective.bootstrap`).
    """

    alpha: float = 0.5
    consistency_weight: float = 0.1
    teacher_velocity_clamp: float | None = None
    freeze_prefix: bool = True
    method: str = "snapflow"
    teacher_velocity: str = "marginal"
    target_time: bool = True
    target: str = "euler"
    target_steps: int | tuple[int, ...] = 2

    def __post_init__(self) -> None:
        if isinstance(self.target_steps, list):  # as read from TOML or JSON
            object.__setattr__(self, "target_steps", tuple(self.target_steps))
        if self.target not in TARGETS:
            raise ValueError(f"unknown SnapFlow target {self.target!r}; choose one of {list(TARGETS)}")
        if self.method not in METHODS:
            raise ValueError(f"unknown distillation method {self.method!r}; choose one of {list(METHODS)}")
        if self.teacher_velocity not in TEACHER_VELOCITIES:
            raise ValueError(f"teacher_velocity must be one of {list(TEACHER_VELOCITIES)}, got {self.teacher_velocity!r}")
        if self.method != "snapflow" and (self.teacher_velocity != "marginal" or self.teacher_velocity_clamp is not None):
            raise ValueError("teacher_velocity and the velocity clamp are options of the snapflow method only")
        if self.method != "snapflow" and (self.target != "euler" or self.target_steps != 2):
            raise ValueError("target and target_steps are options of the snapflow method only")
        if self.target == "bootstrap" and (self.teacher_velocity != "marginal" or self.teacher_velocity_clamp is not None):
            raise ValueError("the bootstrapped target is built from the model's own jumps: it takes no teacher_velocity or clamp")
        self.objective(BetaTimeSampler())  # the objective checks its own settings (target_steps) with named errors

    def objective(self, time_sampler: TimeSampler) -> TwoBranchObjective:
        """The chosen loss with these settings and the policy's own FM time distribution."""
        if self.method == "consistency-distillation":
            return ConsistencyDistillationObjective(self.alpha, self.consistency_weight, time_sampler)
        if self.method == "meanflow":
            return MeanFlowObjective(self.alpha, self.consistency_weight, time_sampler)
        if self.target == "bootstrap":
            if not isinstance(self.target_steps, int):
                raise ValueError(f"a bootstrapped target grows by itself; give target_steps one power of two, not the schedule {list(self.target_steps)}")
            return BootstrappedSnapFlowObjective(self.alpha, self.consistency_weight, time_sampler, self.target_steps)
        return SnapFlowObjective(self.alpha, self.consistency_weight, time_sampler, self.teacher_velocity_clamp, self.teacher_velocity,
                                 self.target_steps)


__all__ = ["DistillSettings", "METHODS", "TARGETS"]
