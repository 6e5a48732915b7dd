"""The two small protocols that connect a policy to SnapFlow, and the optional capabilities a policy may add.

``FlowPolicy`` is all the objective and the samplers ever see. ``TimeEmbeddingModel`` is what a plain
flow-matching policy exposes so that :class:`snapflow.nn.SnapFlowPolicy` can add the target-time
embedding to it without editing its code. ``PaddedActions`` is what a policy whose chunks hold entries its
own loss leaves out (GR00T's padded width) adds, so that the objective leaves them out too. ``PerActionTimes`` is
what a policy whose time enters each action of the chunk on its own (SmolVLA) adds, so that a known prefix of the
chunk can ride at time 0 (:mod:`snapflow.flow.known_prefix`, real-time chunking trained in). The fast paths
(:mod:`snapflow.inference`) ask for the others by ``isinstance``: ``CompiledParts``, ``VisionPrecision``,
``HostSyncFree``, ``PromptPaddingTrim`` and ``FusedOneStep``.

A *context* is whatever ``encode`` returns: a tensor, or a (nested) dict / list / tuple of tensors whose
first dimension is the batch (other leaves pass through untouched). The objective computes it once per
batch and reuses it for every velocity pass, as the real VLAs reuse their prefix (VLM) cache.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, Protocol, runtime_checkable

from torch import Tensor

Context = Any


@runtime_checkable
class FlowPolicy(Protocol):
    """A velocity field F(x_t, s, t | c) with a prefix encoder.

    ``t`` is the current time and ``s`` the target time, both of shape (B,): ``s == t`` asks for the
    instantaneous (marginal) velocity, ``s < t`` for the average velocity of the jump t -> s.
    """

    def encode(self, observation: Any) -> Context:
        """Run the expensive, time-independent part of the policy once per observation batch."""
        ...

    def velocity(self, x_t: Tensor, t: Tensor, s: Tensor, context: Context) -> Tensor:
        """Velocity for noisy actions ``x_t`` of shape (B, *action_shape); same shape out."""
        ...


@runtime_checkable
class TimeEmbeddingModel(Protocol):
    """A plain flow-matching policy split where its time embedding enters.

    ``velocity_from_time_embedding(x_t, embed_time(t), encode(obs))`` must be the policy's usual velocity;
    SnapFlow adds phi_s(s) of width ``time_embedding_dim`` to the embedding in between.
    """

    time_embedding_dim: int

    def encode(self, observation: Any) -> Context: ...

    def embed_time(self, t: Tensor) -> Tensor:
        """Time embedding of shape (B, time_embedding_dim)."""
        ...

    def velocity_from_time_embedding(self, x_t: Tensor, time_embedding: Tensor, context: Context) -> Tensor: ...

    # Optional: ``prefix_parameters() -> list[Parameter]``, the parameters of ``encode`` that distillation keeps
    # frozen by default (see SnapFlowPolicy.expert_parameters).


@runtime_checkable
class PaddedActions(Protocol):
    """A policy whose action chunks hold entries that no loss weighs (padding to a fixed width or length)."""

    def action_weights(self, observation: Any) -> Tensor | None:
        """Per-entry loss weights for the chunks of ``observation``'s batch, broadcastable to (B, *action_shape)
        (1 where an entry counts, 0 where it is padding), or None where every entry counts."""
        ...


@runtime_checkable
class PerActionTimes(Protocol):
    """A policy that takes a time per action of the chunk: ``t`` and ``s`` of shape (B, chunk length), each action's
    own time and target time, so that some actions ride clean (time 0) beside others at any time.

    A wrapper whose model may take one time a chunk (:class:`snapflow.nn.SnapFlowPolicy`) says so in an attribute
    ``per_action_times_refusal``: None where it takes a time per action, else why not (naming the model)."""

    def velocity_per_action(self, x_t: Tensor, t: Tensor, s: Tensor, context: Context) -> Tensor:
        """The velocity as :meth:`FlowPolicy.velocity`, with ``t`` and ``s`` of shape (B, chunk length)."""
        ...


@runtime_checkable
class OwnNoise(Protocol):
    """A policy whose flow starts from another noise than a standard normal (EVO1's, uniform in [-1, 1]): its
    training rows, its offline error and its samples start from it. The others start from a standard normal."""

    def flow_noise(self, shape: tuple[int, ...], generator: Any = None, device: Any = None) -> Tensor:
        """Noise of ``shape`` drawn from ``generator`` (torch's global one where None) on ``device``."""
        ...


def draw_flow_noise(policy: Any, shape: tuple[int, ...], generator: Any = None, device: Any = None) -> Tensor:
    """The noise ``policy``'s flow starts from, of ``shape``: its own (:class:`OwnNoise`) or a standard normal."""
    if isinstance(policy, OwnNoise):
        return policy.flow_noise(tuple(shape), generator, device)
    import torch

    return torch.randn(tuple(shape), generator=generator, device=device)


@runtime_checkable
class CompiledParts(Protocol):
    """A policy that names the two methods a compiled fast path compiles (default: ``encode`` and ``velocity``):
    its prefix pass and its velocity; none where it is one compiled graph already (an ONNX export)."""

    compiled_methods: tuple[str, ...]


@runtime_checkable
class VisionPrecision(Protocol):
    """A policy whose vision tower can run in another dtype than the rest (pi0's SigLIP in bfloat16)."""

    def run_vision_in(self, dtype: Any) -> None: ...


@runtime_checkable
class HostSyncFree(Protocol):
    """A policy that can drop the host synchronisations of its own prefix pass, which a CUDA graph cannot hold."""

    def without_host_syncs(self) -> None: ...


@runtime_checkable
class PromptPaddingTrim(Protocol):
    """A policy whose prompt padding can be cut from a batch without changing a chunk (it is masked out)."""

    def without_prompt_padding(self, batch: Any) -> Any: ...


@runtime_checkable
class FusedOneStep(Protocol):
    """A policy whose one-step chunk (prefix pass and SnapFlow jump) runs as one fused call, as
    :func:`snapflow.inference.compile.fuse_one_step` leaves it."""

    def one_step_chunk(self, observation: Any, noise: Tensor) -> Tensor: ...


def map_tensors(context: Context, function: Callable[[Tensor], Tensor]) -> Context:
    """Apply ``function`` to every tensor in a (nested) context; non-tensor leaves are returned as they are."""
    if isinstance(context, Tensor):
        return function(context)
    if isinstance(context, dict):
        return {key: map_tensors(value, function) for key, value in context.items()}
    if isinstance(context, (list, tuple)):
        mapped = [map_tensors(value, function) for value in context]
        if hasattr(context, "_fields"):  # namedtuple
            return type(context)(*mapped)
        return type(context)(mapped)
    return context


def index_batch(context: Context, index: slice | Tensor) -> Context:
    """Select batch rows from every tensor in a context (an observation or an encoded prefix)."""
    return map_tensors(context, lambda tensor: tensor[index])


__all__ = [
    "OwnNoise",
    "draw_flow_noise",
    "CompiledParts",
    "Context",
    "FlowPolicy",
    "FusedOneStep",
    "HostSyncFree",
    "PaddedActions",
    "PerActionTimes",
    "PromptPaddingTrim",
    "TimeEmbeddingModel",
    "VisionPrecision",
    "index_batch",
    "map_tensors",
]
