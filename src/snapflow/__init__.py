"""SnapFlow: one-step action generation for flow-matching policies by progressive self-distillation."""

from importlib.metadata import version

from snapflow._lazy import lazy_exports

#: the name pip installs snapflow by; the import name stays ``snapflow`` (``snapflow`` on PyPI is an unrelated
#: data-pipeline package, so ``pip install snapflow`` would bring the wrong library)
DISTRIBUTION = "snapflow-vla"
__version__ = version(DISTRIBUTION)


def install_command(extra: str) -> str:
    """The pip command that adds ``extra`` (``lerobot``, ``onnx``, ...) to an installed snapflow."""
    return f'pip install "{DISTRIBUTION}[{extra}]"'


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
            "ShiftedTimeSampler",
        ],
    },
)
