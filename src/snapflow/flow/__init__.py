"""Flow-matching conventions: the probability path, training-time samplers and the Euler solver."""

from snapflow._lazy import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports(
    __name__,
    {
        "snapflow.flow.path": ["interpolate", "conditional_velocity", "euler_step"],
        "snapflow.flow.modes": ["SamplingMode", "TEACHER_10", "NAIVE_1", "SNAPFLOW_1"],
        "snapflow.flow.solver": ["euler_sample", "sample_actions"],
        "snapflow.flow.time_sampling": [
            "TimeSampler",
            "UniformTimeSampler",
            "BetaTimeSampler",
            "Beta22TimeSampler",
            "ShiftedTimeSampler",
            "shifted",
            "time_sampler_for",
        ],
        "snapflow.flow.time_distribution": ["TIME_DISTRIBUTIONS", "UNIFORM", "canonical_time_distribution"],
    },
)
