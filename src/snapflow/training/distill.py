"""Settings of a distillation run, shared by every policy family."""

from __future__ import annotations

from dataclasses import dataclass

from snapflow.flow.time_sampling import TimeSampler
from snapflow.objective import ConsistencyDistillationObjective, MeanFlowObjective, SnapFlowObjective, TwoBranchObjective
from snapflow.objective.snapflow import TEACHER_VELOCITIES

METHODS = ("snapflow", "consistency-distillation", "meanflow")


@dataclass(frozen=True)
class DistillSettings:
    """The paper's defaults: SnapFlow, alpha 0.5, lambda 0.1, no clamp, prefix (VLM) frozen, phi_s attached.

    ``method`` picks the one-step objective (the baselines share alpha and lambda); ``teacher_velocity``
    and ``target_time`` exist for the paper's ablations (conditional velocity; no target-time embedding).
    """

    alpha: float = 0.5
    consistency_weight: float = 0.1
    teacher_velocity_clamp: float | None = None
    freeze_prefix: bool = True
    method: str = "snapflow"
    teacher_velocity: str = "marginal"
    target_time: bool = True

    def __post_init__(self) -> None:
        if self.method not in METHODS:
            raise ValueError(f"unknown distillation method {self.method!r}; choose one of {list(METHODS)}")
        if self.teacher_velocity not in TEACHER_VELOCITIES:
            raise ValueError(f"teacher_velocity must be one of {list(TEACHER_VELOCITIES)}, got {self.teacher_velocity!r}")
        if self.method != "snapflow" and (self.teacher_velocity != "marginal" or self.teacher_velocity_clamp is not None):
            raise ValueError("teacher_velocity and the velocity clamp are options of the snapflow method only")

    def objective(self, time_sampler: TimeSampler) -> TwoBranchObjective:
        """The chosen loss with these settings and the policy's own FM time distribution."""
        if self.method == "consistency-distillation":
            return ConsistencyDistillationObjective(self.alpha, self.consistency_weight, time_sampler)
        if self.method == "meanflow":
            return MeanFlowObjective(self.alpha, self.consistency_weight, time_sampler)
        return SnapFlowObjective(self.alpha, self.consistency_weight, time_sampler, self.teacher_velocity_clamp, self.teacher_velocity)


__all__ = ["DistillSettings", "METHODS"]
