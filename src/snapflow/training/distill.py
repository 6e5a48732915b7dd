"""Settings of a SnapFlow distillation run, shared by every policy family."""

from __future__ import annotations

from dataclasses import dataclass

from snapflow.flow.time_sampling import TimeSampler
from snapflow.objective.snapflow import SnapFlowObjective


@dataclass(frozen=True)
class DistillSettings:
    """The paper's defaults: alpha 0.5, lambda 0.1, no clamp, prefix (VLM) frozen."""

    alpha: float = 0.5
    consistency_weight: float = 0.1
    teacher_velocity_clamp: float | None = None
    freeze_prefix: bool = True

    def objective(self, time_sampler: TimeSampler) -> SnapFlowObjective:
        """The SnapFlow loss with these settings and the policy's own FM time distribution."""
        return SnapFlowObjective(self.alpha, self.consistency_weight, time_sampler, self.teacher_velocity_clamp)


__all__ = ["DistillSettings"]
