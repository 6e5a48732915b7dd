"""Flow-matching conventions: the probability path, training-time samplers and the Euler solver."""

from snapflow.flow.path import conditional_velocity, euler_step, interpolate
from snapflow.flow.solver import NAIVE_1, SNAPFLOW_1, TEACHER_10, SamplingMode, euler_sample, sample_actions
from snapflow.flow.time_sampling import BetaTimeSampler, TimeSampler, UniformTimeSampler

__all__ = [
    "interpolate",
    "conditional_velocity",
    "euler_step",
    "SamplingMode",
    "TEACHER_10",
    "NAIVE_1",
    "SNAPFLOW_1",
    "euler_sample",
    "sample_actions",
    "TimeSampler",
    "UniformTimeSampler",
    "BetaTimeSampler",
]
