"""MiniVLA: the built-in compact vision-language-action policy (configuration, modeling, processor)."""

from snapflow.policies.minivla.configuration import MiniVLAConfig
from snapflow.policies.minivla.modeling import MiniVLA
from snapflow.policies.minivla.processor import MiniVLAProcessor

__all__ = ["MiniVLAConfig", "MiniVLA", "MiniVLAProcessor"]
