"""The torch.compile fast paths: a policy's prefix pass and its one-pass velocity, both compiled (registered by mode
in :mod:`snapflow.inference.fast_paths`: ``compile``, ``compile-reduce-overhead``, ``compile-max-autotune``).

``torch.compile`` replaces the two methods on the instance, so every sampler that calls them runs compiled:
:func:`snapflow.flow.sample_actions` (``snapflow eval``, ``snapflow bench``) and a LeRobot adapter's
``use_sampling_mode`` (LeRobot's own ``select_action`` / ``predict_action_chunk``). With ``reduce-overhead`` on a GPU
each is captured in a CUDA graph; the prefix's outputs (the key/value cache the jump reads) are copied out of the
graph's static buffers, which its next replay overwrites.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, Any, Literal, get_args

if TYPE_CHECKING:
    from torch import nn

CompileMode = Literal["default", "reduce-overhead", "max-autotune"]
COMPILE_MODES: tuple[str, ...] = get_args(CompileMode)
#: what a policy compiles unless it names its own (``compiled_methods``): its prefix pass, then its velocity
DEFAULT_METHODS = ("encode", "velocity")


def compile_policy(policy: nn.Module, mode: CompileMode = "default") -> nn.Module:
    """Compile ``policy``'s prefix pass and velocity in place (``policy.compiled_methods``, by default
    ``encode`` and ``velocity``); returns ``policy``."""
    if mode not in COMPILE_MODES:
        raise ValueError(f"unknown compile mode {mode!r}; choose one of {', '.join(COMPILE_MODES)}")
    import torch  # here, not at import: the CLI lists the modes before torch loads

    methods = getattr(policy, "compiled_methods", DEFAULT_METHODS)
    if not methods:  # already a compiled graph (an ONNX export)
        return policy
    prefix, velocity = methods
    setattr(policy, prefix, _kept_outputs(torch.compile(getattr(policy, prefix), mode=mode, dynamic=False), mode))
    setattr(policy, velocity, torch.compile(getattr(policy, velocity), mode=mode, dynamic=False))
    return policy


def compile_default(policy: nn.Module) -> nn.Module:
    """The ``compile`` fast path: :func:`compile_policy` in mode ``default``."""
    return compile_policy(policy, "default")


def compile_reduce_overhead(policy: nn.Module) -> nn.Module:
    """The ``compile-reduce-overhead`` fast path: :func:`compile_policy` in mode ``reduce-overhead``."""
    return compile_policy(policy, "reduce-overhead")


def compile_max_autotune(policy: nn.Module) -> nn.Module:
    """The ``compile-max-autotune`` fast path: :func:`compile_policy` in mode ``max-autotune``."""
    return compile_policy(policy, "max-autotune")


def _kept_outputs(compiled: Callable[..., Any], mode: str) -> Callable[..., Any]:
    """Under CUDA graphs (``reduce-overhead``), the prefix's outputs copied out of the graph: the jump reads them,
    and may extend a cache in place, after the graph has been replayed again."""
    if mode != "reduce-overhead":
        return compiled
    import torch

    from snapflow.protocol import map_tensors

    def run(*args: Any, **kwargs: Any) -> Any:
        torch.compiler.cudagraph_mark_step_begin()
        return map_tensors(compiled(*args, **kwargs), torch.clone)

    return run


__all__ = [
    "CompileMode",
    "COMPILE_MODES",
    "DEFAULT_METHODS",
    "compile_policy",
    "compile_default",
    "compile_reduce_overhead",
    "compile_max_autotune",
]
