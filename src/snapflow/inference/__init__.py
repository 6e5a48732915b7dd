"""Inference-time speed: the deployment fast paths, applied to any FlowPolicy (built-in or LeRobot adapter)."""

from snapflow.inference.compile import COMPILE_MODES, compile_policy

__all__ = ["COMPILE_MODES", "compile_policy"]
