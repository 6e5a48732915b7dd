"""The torch.compile fast paths: a policy's prefix pass and its one-pass velocity, both compiled (registered by mode
in :mod:`snapflow.inference.fast_paths`: ``compile``, ``compile-reduce-overhead``, ``compile-max-autotune``).

``torch.compile`` replaces the two methods on the instance, so every sampler that calls them runs compiled:
:func:`snapflow.flow.sample_actions` (``snapflow eval``, ``snapflow bench``) and a LeRobot adapter's
``use_sampling_mode`` (LeRobot's own ``select_action`` / ``predict_action_chunk``). With ``reduce-overhead`` on a GPU
each is captured in a CUDA graph; the prefix's outputs (the key/value cache the jump reads) are copied out of the
graph's static buffers, which its next replay overwrites.

:func:`fuse_one_step` compiles the whole one-step chunk, the prefix pass and the jump, as one graph
(``policy.one_step_chunk``, which :func:`snapflow.flow.sample_actions` runs for SnapFlow 1-NFE): under
``reduce-overhead`` one CUDA graph a chunk, nothing copied between the two.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, Any, Literal, get_args

from snapflow.errors import InvalidInputError

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
        raise InvalidInputError(f"unknown compile mode {mode!r}; choose one of {', '.join(COMPILE_MODES)}")
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


def fuse_one_step(policy: nn.Module, mode: CompileMode = "reduce-overhead") -> nn.Module:
    """Compile ``policy``'s one-step chunk, prefix pass and SnapFlow jump, as one graph, set as
    ``policy.one_step_chunk(observation, noise)``; returns ``policy``.

    The graph is traced through the policy's own (eager) methods: where :func:`compile_policy` has put compiled
    ones on the instance, they step aside for the fused call, so that one graph holds both parts instead of two
    compiled calls with a copy between them.
    """
    if mode not in COMPILE_MODES:
        raise InvalidInputError(f"unknown compile mode {mode!r}; choose one of {', '.join(COMPILE_MODES)}")
    import torch

    from snapflow.flow.modes import SNAPFLOW_1
    from snapflow.flow.solver import euler_sample

    methods = getattr(policy, "compiled_methods", DEFAULT_METHODS)
    if not methods:  # already one graph (an ONNX export)
        return policy

    def chunk(observation: Any, noise: torch.Tensor) -> torch.Tensor:
        context = policy.encode(observation)
        return euler_sample(lambda x, t, s: policy.velocity(x, t, s, context), noise, SNAPFLOW_1)

    fused = torch.compile(chunk, mode=mode, dynamic=False)

    def one_step_chunk(observation: Any, noise: torch.Tensor) -> torch.Tensor:
        # any method the instance overrides steps aside: compiled ones, and a wrapper a fast path put around encode
        names = dict.fromkeys((*methods, *DEFAULT_METHODS))
        stepped_aside = {name: policy.__dict__.pop(name) for name in names if name in policy.__dict__}
        try:
            if mode != "reduce-overhead":
                return fused(observation, noise)
            torch.compiler.cudagraph_mark_step_begin()
            return fused(observation, noise).clone()  # the graph's output buffer is overwritten by its next replay
        finally:
            policy.__dict__.update(stepped_aside)

    policy.one_step_chunk = one_step_chunk
    return policy


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
    "fuse_one_step",
    "compile_default",
    "compile_reduce_overhead",
    "compile_max_autotune",
]
