"""Demonstrations: collection from a benchmark's experts, storage, and (observation, action chunk) training pairs."""

from snapflow._lazy import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports(
    __name__,
    {
        "snapflow.data.demonstrations": ["Demonstrations", "DemonstrationError", "Episode"],
    },
)
