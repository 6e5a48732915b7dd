"""Inference-time speed, for any FlowPolicy (built-in or LeRobot adapter): the deployment fast paths by name (the
compiled prefix and expert) and the export formats (one ONNX graph)."""

from snapflow._lazy import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports(
    __name__,
    {
        "snapflow.inference.compile": ["COMPILE_MODES", "compile_policy"],
        "snapflow.inference.fast_paths": ["FAST_PATHS", "apply_fast_path", "fast_path", "register_fast_path"],
        "snapflow.inference.onnx": ["OnnxOneStepPolicy", "export_onnx"],
    },
)
