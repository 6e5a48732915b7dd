"""Neural building blocks SnapFlow adds to a policy."""

from snapflow._lazy import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports(
    __name__,
    {
        "snapflow.nn.snapflow_policy": ["SnapFlowPolicy"],
        "snapflow.nn.time_embedding": ["TargetTimeEmbedding", "sinusoidal_features"],
    },
)
