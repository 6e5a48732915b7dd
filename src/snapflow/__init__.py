"""SnapFlow: one-step action generation for flow-matching policies by progressive self-distillation."""

from importlib.metadata import version

from snapflow._lazy import lazy_exports

__version__ = version("snapflow")

__getattr__, __dir__, __all__ = lazy_exports(
    __name__,
    {
        "snapflow.protocol": ["FlowPolicy", "TimeEmbeddingModel"],
        "snapflow.nn": ["SnapFlowPolicy", "TargetTimeEmbedding"],
        "snapflow.objective": ["SnapFlowObjective", "LossOutput"],
        "snapflow.flow": [
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
        ],
    },
)
