"""Distillation objectives: SnapFlow, and the one-step baselines it is compared with, on one base."""

from snapflow.objective.base import LossOutput, OneStepRows, TwoBranchObjective
from snapflow.objective.bootstrap import BootstrappedSnapFlowObjective
from snapflow.objective.consistency_distillation import ConsistencyDistillationObjective
from snapflow.objective.meanflow import MeanFlowObjective
from snapflow.objective.registry import OBJECTIVES, make_objective
from snapflow.objective.snapflow import SnapFlowObjective, euler_shortcut_target

__all__ = [
    "BootstrappedSnapFlowObjective",
    "ConsistencyDistillationObjective",
    "LossOutput",
    "MeanFlowObjective",
    "OBJECTIVES",
    "make_objective",
    "OneStepRows",
    "SnapFlowObjective",
    "TwoBranchObjective",
    "euler_shortcut_target",
]
