"""The torch.compile fast paths: a policy's prefix pass and its one-pass velocity, both compiled (registered by mode
in :mod:`snapflow.inference.fast_paths`: ``compile``, ``compile-reduce-overhead``, ``compile-max-autotune``).

``torch.compile`` replaces the two methods on the instance, so every sampler that calls them runs compiled:
:func:`snapflow.flow.sample_actions` (``snapflow eval``, ``snapflow bench``) and a LeRobot adapter's
``use_sampling_mode`` (LeRobot's own ``select_action`` / ``predict_action_chunk``). With ``reduce-overhead`` on a GPU
each is captured in a CUDA graph; the prefix's outputs (the key/value cache the jump reads) are copied out of the
graph's static buffers, which its next replay overwrites.

:func:`fuse_one_step` compiles the whole one-step chunk, the prefix pass and the jump, as one graph
(``policy.one_step_chunk``, which :func:`snapflow.flow.sample_actions` runs for SnapFlow 1-NFE): under
``reduce-overhead`` on a GPU, one CUDA graph a chunk that the chunk replays directly (:class:`CudaGraphReplay`), with
no copy between the two parts and none of torch.compile's per-call work (its guards, and CUDA-graph trees' checks of
every parameter: 2.9 ms a chunk of pi0.5's 12.9 ms on an H200, beside 10.0 ms of kernels).
"""

from __future__ import annotations

import warnings
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

    from snapflow.protocol import CompiledParts

    methods = policy.compiled_methods if isinstance(policy, CompiledParts) else DEFAULT_METHODS
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
    from snapflow.protocol import CompiledParts

    methods = policy.compiled_methods if isinstance(policy, CompiledParts) else DEFAULT_METHODS
    if not methods:  # already one graph (an ONNX export)
        return policy

    def chunk(observation: Any, noise: torch.Tensor) -> torch.Tensor:
        context = policy.encode(observation)
        return euler_sample(lambda x, t, s: policy.velocity(x, t, s, context), noise, SNAPFLOW_1)

    # reduce-overhead's CUDA graph is captured here, around code compiled without one of torch.compile's own
    fused = torch.compile(chunk, mode="default" if mode == "reduce-overhead" else mode, dynamic=False)
    replay = CudaGraphReplay(fused) if mode == "reduce-overhead" else None

    def one_step_chunk(observation: Any, noise: torch.Tensor) -> torch.Tensor:
        # any method the instance overrides steps aside: compiled ones, and a wrapper a fast path put around encode
        names = dict.fromkeys((*methods, *DEFAULT_METHODS))
        stepped_aside = {name: policy.__dict__.pop(name) for name in names if name in policy.__dict__}
        try:
            if replay is not None and noise.is_cuda:
                return replay(observation, noise)
            return fused(observation, noise)
        finally:
            policy.__dict__.update(stepped_aside)

    policy.one_step_chunk = one_step_chunk
    return policy


class CudaGraphReplay:
    """``function`` (tensors, or dicts, lists and tuples of them, in; one tensor out) run as CUDA graphs: one captured
    per signature of its arguments (their structure, each tensor's shape, dtype and device, every other leaf's
    value), then replayed with the arguments copied into the graph's own input buffers. A replay is one launch from
    the host, whatever the function's size. A function that cannot be captured (a host synchronisation inside it,
    such as a shape read from the data) runs as it is, with a warning that says why."""

    #: calls before a capture, outside it: torch.compile compiles, kernels autotune and lazy state initialises
    WARMUP_CALLS = 2

    def __init__(self, function: Callable[..., Any]) -> None:
        self.function = function
        self.graphs: dict[tuple[Any, ...], tuple[list[Any], Any, Any] | None] = {}  # None: not capturable

    def __call__(self, *arguments: Any) -> Any:
        from torch.utils._pytree import tree_flatten

        leaves, spec = tree_flatten(arguments)
        signature = (str(spec), *(_leaf_signature(leaf) for leaf in leaves))
        if signature not in self.graphs:
            self.graphs[signature] = self._capture(leaves, spec)
        captured = self.graphs[signature]
        if captured is None:
            return self.function(*arguments)
        inputs, graph, output = captured
        for buffer, leaf in zip(inputs, leaves, strict=True):
            if buffer is not None:
                buffer.copy_(leaf)
        graph.replay()
        return output.clone()  # the graph's output buffer is overwritten by its next replay

    def _capture(self, leaves: list[Any], spec: Any) -> tuple[list[Any], Any, Any] | None:
        """The graph of one signature, from its flattened arguments; None when it cannot be captured."""
        import torch
        from torch.utils._pytree import tree_unflatten

        with torch.inference_mode(False):  # buffers a later call may fill outside inference mode too
            inputs = [leaf.clone() if isinstance(leaf, torch.Tensor) else None for leaf in leaves]
        static = tree_unflatten(
            [leaf if buffer is None else buffer for buffer, leaf in zip(inputs, leaves, strict=True)], spec
        )
        side = torch.cuda.Stream()
        side.wait_stream(torch.cuda.current_stream())
        with torch.cuda.stream(side):
            for _ in range(self.WARMUP_CALLS):
                self.function(*static)
        torch.cuda.current_stream().wait_stream(side)
        graph = torch.cuda.CUDAGraph()
        try:
            with torch.cuda.graph(graph):
                output = self.function(*static)
        except RuntimeError as error:  # CUDA's capture errors; the capture has ended, the device goes on
            cause = error.__context__ or error  # the operation the capture refused, before capture_end's own error
            reason = str(cause).strip().splitlines()[0]
            warnings.warn(
                f"{self.function!r} runs without a CUDA graph: it cannot be captured ({reason})", stacklevel=3
            )
            return None
        return inputs, graph, output


def _leaf_signature(leaf: Any) -> Any:
    import torch

    if isinstance(leaf, torch.Tensor):
        return (tuple(leaf.shape), leaf.dtype, leaf.device)
    try:
        hash(leaf)
    except TypeError:
        return repr(leaf)
    return leaf


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
    "CudaGraphReplay",
    "DEFAULT_METHODS",
    "compile_policy",
    "fuse_one_step",
    "compile_default",
    "compile_reduce_overhead",
    "compile_max_autotune",
]
