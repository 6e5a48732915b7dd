"""A policy whose flow starts from its own noise (``OwnNoise``, EVO1's uniform in [-1, 1]): the objective's rows, the
trainer's draws and the offline error start from it, the same draws for the same generator; any other policy starts
from a standard normal, exactly as before the capability existed."""

from __future__ import annotations

import torch
from torch import nn

from snapflow.flow import UniformTimeSampler
from snapflow.objective import SnapFlowObjective
from snapflow.protocol import OwnNoise, draw_flow_noise


class RecordingPolicy(nn.Module):
    """A velocity of zero that records every x_t it is asked about."""

    def __init__(self) -> None:
        super().__init__()
        self.scale = nn.Parameter(torch.zeros(()))
        self.inputs: list[torch.Tensor] = []

    def encode(self, observation):
        return {"observation": observation}

    def velocity(self, x_t, t, s, context):
        self.inputs.append(x_t.detach().clone())
        return x_t * self.scale


class UniformNoisePolicy(RecordingPolicy):
    def flow_noise(self, shape, generator=None, device=None):
        return torch.rand(shape, generator=generator, device=device) * 2 - 1


def test_the_capability_is_claimed_by_the_method_alone():
    assert isinstance(UniformNoisePolicy(), OwnNoise) and not isinstance(RecordingPolicy(), OwnNoise)


def test_a_policys_own_noise_is_drawn_from_the_generator_and_a_plain_policy_gets_a_standard_normal():
    shape = (4, 8, 3)
    own = draw_flow_noise(UniformNoisePolicy(), shape, torch.Generator().manual_seed(1))
    assert torch.equal(own, torch.rand(shape, generator=torch.Generator().manual_seed(1)) * 2 - 1)
    plain = draw_flow_noise(RecordingPolicy(), shape, torch.Generator().manual_seed(1))
    assert torch.equal(plain, torch.randn(shape, generator=torch.Generator().manual_seed(1)))


def test_the_flow_matching_rows_start_from_the_policys_own_noise():
    """At t = 1 a flow-matching row's input is its noise itself: uniform in [-1, 1] (variance 1/3), never a normal's
    tails."""
    policy, actions = UniformNoisePolicy(), torch.zeros(512, 8, 3)
    objective = SnapFlowObjective(alpha=1.0, time_sampler=UniformTimeSampler())
    objective(policy, torch.zeros(512, 2), actions, time=torch.ones(512), generator=torch.Generator().manual_seed(0))
    (noise,) = policy.inputs
    assert noise.abs().max() <= 1 and abs(noise.var().item() - 1 / 3) < 0.02
    plain = RecordingPolicy()
    objective(plain, torch.zeros(512, 2), actions, time=torch.ones(512), generator=torch.Generator().manual_seed(0))
    assert plain.inputs[0].abs().max() > 3  # a standard normal's tails, over 12,288 draws
