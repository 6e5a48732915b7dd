"""MLP flow-matching policy over a flat observation vector (configuration, modeling, processor)."""

from snapflow._lazy import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports(
    __name__,
    {
        "snapflow.policies.mlp.configuration": ["MLPPolicyConfig"],
        "snapflow.policies.mlp.modeling": ["MLPFlowModel"],
        "snapflow.policies.mlp.processor": ["MLPProcessor"],
    },
)
