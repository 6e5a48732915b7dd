"""Test helpers: a small real policy, and a recorder that sees every call the objective makes."""

from __future__ import annotations

from dataclasses import dataclass, field

import torch
from torch import Tensor, nn

from snapflow.nn import SnapFlowPolicy
from snapflow.policies.mlp import MLPFlowModel, MLPPolicyConfig

OBSERVATION_DIM, CHUNK, ACTION_DIM = 5, 3, 2


def make_model(seed: int = 0) -> MLPFlowModel:
    torch.manual_seed(seed)
    return MLPFlowModel(
        MLPPolicyConfig(observation_dim=OBSERVATION_DIM, action_dim=ACTION_DIM, chunk_length=CHUNK, hidden_dim=32, time_embedding_dim=16)
    )


def randomise_target_time(policy: SnapFlowPolicy, seed: int = 1) -> SnapFlowPolicy:
    """Give phi_s a non-zero last layer, standing in for a partly trained student whose output depends on s."""
    generator = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for parameter in policy.target_time_embedding.linear_out.parameters():
            parameter.copy_(0.3 * torch.randn(parameter.shape, generator=generator))
    return policy


@dataclass
class Call:
    x: Tensor
    t: Tensor
    s: Tensor
    output: Tensor
    grad_enabled: bool


@dataclass
class RecordingPolicy:
    """Forwards to a real FlowPolicy and records each encode and velocity call."""

    policy: nn.Module
    encodes: int = 0
    calls: list[Call] = field(default_factory=list)

    def encode(self, observation):
        self.encodes += 1
        return self.policy.encode(observation)

    def velocity(self, x_t, t, s, context):
        output = self.policy.velocity(x_t, t, s, context)
        self.calls.append(Call(x_t.detach().clone(), t.clone(), s.clone(), output, torch.is_grad_enabled()))
        return output
