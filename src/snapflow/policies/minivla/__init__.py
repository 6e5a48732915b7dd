"""MiniVLA: the built-in compact vision-language-action policy (configuration, modeling, processor)."""

from snapflow._lazy import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports(
    __name__,
    {
        "snapflow.policies.minivla.configuration": ["MiniVLAConfig"],
        "snapflow.policies.minivla.modeling": ["MiniVLA"],
        "snapflow.policies.minivla.processor": ["MiniVLAProcessor"],
    },
)
