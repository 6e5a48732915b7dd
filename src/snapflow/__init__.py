"""SnapFlow: one-step action generation for flow-matching policies by progressive self-distillation."""

from importlib.metadata import version

from snapflow.flow import (
    NAIVE_1,
    SNAPFLOW_1,
    TEACHER_10,
    BetaTimeSampler,
    SamplingMode,
    UniformTimeSampler,
    conditional_velocity,
    euler_sample,
    interpolate,
    sample_actions,
)
from snapflow.nn import SnapFlowPolicy, TargetTimeEmbedding
from snapflow.objective import LossOutput, SnapFlowObjective
from snapflow.protocol import FlowPolicy, TimeEmbeddingModel

__version__ = version("snapflow")

__all__ = [
    "FlowPolicy",
    "TimeEmbeddingModel",
    "SnapFlowPolicy",
    "TargetTimeEmbedding",
    "SnapFlowObjective",
    "LossOutput",
    "SamplingMode",
    "TEACHER_10",
    "NAIVE_1",
    "SNAPFLOW_1",
    "sample_actions",
    "euler_sample",
    "interpolate",
    "conditional_velocity",
    "UniformTimeSampler",
    "BetaTimeSampler",
]
