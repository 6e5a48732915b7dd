"""An MLP velocity field: the smallest policy that speaks :class:`snapflow.protocol.TimeEmbeddingModel`."""

from __future__ import annotations

import torch
from torch import Tensor, nn

from snapflow.nn.time_embedding import sinusoidal_features
from snapflow.policies.mlp.configuration import MLPPolicyConfig


class MLPFlowModel(nn.Module):
    """Observation -> embedding (the "prefix", computed once), then an MLP over [x_t, time emb, prefix]."""

    def __init__(self, config: MLPPolicyConfig) -> None:
        super().__init__()
        self.config = config
        self.time_embedding_dim = config.time_embedding_dim
        width = config.hidden_dim
        self.observation_encoder = nn.Sequential(nn.Linear(config.observation_dim, width), nn.SiLU())
        self.time_mlp = nn.Sequential(
            nn.Linear(config.time_embedding_dim, config.time_embedding_dim),
            nn.SiLU(),
            nn.Linear(config.time_embedding_dim, config.time_embedding_dim),
        )
        action_size = config.chunk_length * config.action_dim
        layers: list[nn.Module] = [nn.Linear(action_size + config.time_embedding_dim + width, width), nn.SiLU()]
        for _ in range(config.num_layers - 1):
            layers += [nn.Linear(width, width), nn.SiLU()]
        layers.append(nn.Linear(width, action_size))
        self.velocity_mlp = nn.Sequential(*layers)

    def prefix_parameters(self) -> list[nn.Parameter]:
        """The observation encoder: the "prefix", frozen during distillation by default."""
        return list(self.observation_encoder.parameters())

    def encode(self, observation: Tensor) -> Tensor:
        if observation.ndim != 2 or observation.shape[1] != self.config.observation_dim:
            raise ValueError(
                f"observation must have shape (B, {self.config.observation_dim}), got {tuple(observation.shape)}"
            )
        return self.observation_encoder(observation)

    def embed_time(self, t: Tensor) -> Tensor:
        return self.time_mlp(sinusoidal_features(t, self.time_embedding_dim).to(self.time_mlp[0].weight.dtype))

    def velocity_from_time_embedding(self, x_t: Tensor, time_embedding: Tensor, context: Tensor) -> Tensor:
        expected = (self.config.chunk_length, self.config.action_dim)
        if tuple(x_t.shape[1:]) != expected:
            raise ValueError(f"noisy actions must have shape (B, {expected[0]}, {expected[1]}), got {tuple(x_t.shape)}")
        features = torch.cat([x_t.flatten(1), nn.functional.silu(time_embedding), context], dim=1)
        hidden = self.velocity_mlp(features)
        return hidden.view_as(x_t)
