"""MLP flow-matching policy over a flat observation vector (configuration, modeling, processor)."""

from snapflow.policies.mlp.configuration import MLPPolicyConfig
from snapflow.policies.mlp.modeling import MLPFlowModel
from snapflow.policies.mlp.processor import MLPProcessor

__all__ = ["MLPPolicyConfig", "MLPFlowModel", "MLPProcessor"]
