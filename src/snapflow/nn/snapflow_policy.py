"""Turn a plain flow-matching policy into a SnapFlow one without touching its code."""

from __future__ import annotations

from typing import Any

from torch import Tensor, nn

from snapflow.errors import InvalidInputError
from snapflow.nn.time_embedding import TargetTimeEmbedding
from snapflow.protocol import Context


class SnapFlowPolicy(nn.Module):
    """Implements :class:`snapflow.protocol.FlowPolicy` for a :class:`snapflow.protocol.TimeEmbeddingModel`.

    The velocity is ``model.velocity_from_time_embedding(x_t, model.embed_time(t) + phi_s(s), context)``.
    A model whose class declares ``per_action_times = True`` (a transformer over the chunk's actions) takes a time
    embedding per action too, (B, chunk, width): :meth:`velocity_per_action` then answers
    :class:`~snapflow.protocol.PerActionTimes`.
    With ``target_time=False`` there is no phi_s and s is ignored: that is the flow-matching teacher, and
    the "without phi_s" ablation of the paper.

    Args:
        model: the plain flow-matching policy: ``encode``, ``embed_time``, ``velocity_from_time_embedding`` and an
            integer ``time_embedding_dim``.
        target_time: add phi_s (zero at init, so the student starts bit-identical to its teacher); False: the
            teacher, whose velocity ignores s.

    Raises:
        TypeError: ``model`` lacks a method or the integer ``time_embedding_dim`` of the protocol.

    Examples:
        A student and its teacher around one built-in MLP: at init, phi_s being zero, the student's jump is the
        teacher's naive step.

        >>> import torch
        >>> from snapflow import NAIVE_1, SNAPFLOW_1, SnapFlowPolicy, sample_actions
        >>> from snapflow.policies.mlp import MLPFlowModel, MLPPolicyConfig
        >>> config = MLPPolicyConfig(
        ...     observation_dim=4, action_dim=2, chunk_length=3, hidden_dim=32
        ... )
        >>> model = MLPFlowModel(config)
        >>> student = SnapFlowPolicy(model)
        >>> teacher = SnapFlowPolicy(model, target_time=False)
        >>> observation, noise = torch.randn(5, 4), torch.randn(5, 3, 2)
        >>> jump = sample_actions(student, observation, noise, SNAPFLOW_1)
        >>> torch.equal(jump, sample_actions(teacher, observation, noise, NAIVE_1))
        True
    """

    def __init__(self, model: nn.Module, target_time: bool = True) -> None:
        super().__init__()
        missing = [
            name
            for name in ("encode", "embed_time", "velocity_from_time_embedding")
            if not callable(getattr(model, name, None))
        ]
        if missing:
            raise TypeError(
                f"{type(model).__name__} lacks {', '.join(missing)}(); see snapflow.protocol.TimeEmbeddingModel"
            )
        if not isinstance(getattr(model, "time_embedding_dim", None), int):
            raise TypeError(f"{type(model).__name__} must define an integer time_embedding_dim")
        self.model = model
        self.target_time_embedding = TargetTimeEmbedding(model.time_embedding_dim) if target_time else None

    def expert_parameters(self) -> list[nn.Parameter]:
        """What distillation trains with the prefix frozen, as the paper freezes the VLM: every parameter but the
        model's ``prefix_parameters()`` (all of them for a model without a prefix), phi_s included."""
        prefix = getattr(self.model, "prefix_parameters", None)
        frozen = {id(parameter) for parameter in prefix()} if prefix is not None else set()
        return [parameter for parameter in self.parameters() if id(parameter) not in frozen]

    def encode(self, observation: Any) -> Context:
        return self.model.encode(observation)

    def velocity(self, x_t: Tensor, t: Tensor, s: Tensor, context: Context) -> Tensor:
        time_embedding = self.model.embed_time(t)
        if self.target_time_embedding is not None:
            time_embedding = time_embedding + self.target_time_embedding(s).to(time_embedding.dtype)
        return self.model.velocity_from_time_embedding(x_t, time_embedding, context)

    @property
    def per_action_times_refusal(self) -> str | None:
        """None where the model takes a time per action (its class declares ``per_action_times = True``), else why
        not (:class:`~snapflow.protocol.PerActionTimes`)."""
        if getattr(type(self.model), "per_action_times", False) is True:
            return None
        return f"{type(self.model).__name__} takes one time a chunk"

    def velocity_per_action(self, x_t: Tensor, t: Tensor, s: Tensor, context: Context) -> Tensor:
        """The velocity with ``t`` and ``s`` of shape (B, chunk): each action's time and target time, embedded
        flattened and given to the model as a time embedding per action.

        Raises:
            InvalidInputError: the model takes one time a chunk (the MLP policy).
        """
        refusal = self.per_action_times_refusal
        if refusal is not None:
            raise InvalidInputError(f"{refusal}: it cannot be given a time per action (real-time chunking trained in)")
        batch, chunk = t.shape
        time_embedding = self.model.embed_time(t.reshape(-1))
        if self.target_time_embedding is not None:
            time_embedding = time_embedding + self.target_time_embedding(s.reshape(-1)).to(time_embedding.dtype)
        return self.model.velocity_from_time_embedding(x_t, time_embedding.reshape(batch, chunk, -1), context)


__all__ = ["SnapFlowPolicy"]
