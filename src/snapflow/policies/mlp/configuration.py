"""Configuration of the MLP flow-matching policy."""

from __future__ import annotations

from dataclasses import dataclass

from snapflow.errors import InvalidInputError
from snapflow.policies.configuration import PolicyConfig


@dataclass(frozen=True)
class MLPPolicyConfig(PolicyConfig):
    """A flat observation vector in, an action chunk of ``chunk_length`` x ``action_dim`` out.

    On an environment the observation is the normalised state followed by a one-hot of the task's instruction
    (:class:`snapflow.policies.mlp.MLPProcessor`), so ``observation_dim`` = state entries read + instructions.
    """

    observation_dim: int
    action_dim: int
    chunk_length: int = 1
    hidden_dim: int = 256
    num_layers: int = 3
    time_embedding_dim: int = 64

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.time_embedding_dim % 2:
            raise InvalidInputError(f"MLPPolicyConfig.time_embedding_dim must be even, got {self.time_embedding_dim}")
