"""Configuration of the MLP flow-matching policy."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class MLPPolicyConfig:
    """A flat observation vector in, an action chunk of ``chunk_length`` x ``action_dim`` out."""

    observation_dim: int
    action_dim: int
    chunk_length: int = 1
    hidden_dim: int = 256
    num_layers: int = 3
    time_embedding_dim: int = 64

    def __post_init__(self) -> None:
        for name in ("observation_dim", "action_dim", "chunk_length", "hidden_dim", "num_layers", "time_embedding_dim"):
            if getattr(self, name) < 1:
                raise ValueError(f"MLPPolicyConfig.{name} must be at least 1, got {getattr(self, name)}")
        if self.time_embedding_dim % 2:
            raise ValueError(f"MLPPolicyConfig.time_embedding_dim must be even, got {self.time_embedding_dim}")
