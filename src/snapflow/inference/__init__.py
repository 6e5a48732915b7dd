"""Inference-time speed: the deployment fast paths (compiled prefix and expert; one ONNX graph), applied to any
FlowPolicy (built-in or LeRobot adapter)."""

from snapflow._lazy import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports(
    __name__,
    {
        "snapflow.inference.compile": ["COMPILE_MODES", "compile_policy"],
        "snapflow.inference.onnx": ["OnnxOneStepPolicy", "export_onnx"],
    },
)
