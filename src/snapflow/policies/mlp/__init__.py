"""MLP flow-matching policy over a flat observation vector."""

from snapflow.policies.mlp.configuration import MLPPolicyConfig
from snapflow.policies.mlp.modeling import MLPFlowModel

__all__ = ["MLPPolicyConfig", "MLPFlowModel"]
