"""Distillation objectives: SnapFlow, and the one-step baselines it is compared with, on one base."""

from snapflow._lazy import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports(
    __name__,
    {
        "snapflow.objective.bootstrap": ["BootstrappedSnapFlowObjective"],
        "snapflow.objective.consistency_distillation": ["ConsistencyDistillationObjective"],
        "snapflow.objective.base": ["LossOutput", "OneStepRows", "SetRows", "TwoBranchObjective"],
        "snapflow.objective.energy": ["EnergySnapFlowObjective"],
        "snapflow.objective.meanflow": ["MeanFlowObjective"],
        "snapflow.objective.registry": ["OBJECTIVES", "ObjectiveType", "make_objective", "register_objective"],
        "snapflow.objective.settings": ["DistillSettings"],
        "snapflow.objective.snapflow": ["SnapFlowObjective", "euler_shortcut_target"],
    },
)
