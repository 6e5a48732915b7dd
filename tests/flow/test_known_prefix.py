"""A chunk's known first actions (real-time chunking trained in): the view every pass runs through, by hand, and a
policy that learns to continue a prefix where the bare one-step jump picks its mode by the noise."""

from __future__ import annotations

import pytest
import torch
from torch import Tensor, nn

from snapflow.errors import InvalidInputError
from snapflow.flow.known_prefix import KnownPrefixPolicy, prefix_mask, sample_continuing
from snapflow.flow.modes import SNAPFLOW_1, TEACHER_10, SamplingMode
from snapflow.nn.time_embedding import sinusoidal_features
from snapflow.objective.settings import DistillSettings
from snapflow.protocol import PerActionTimes
from tests.helpers import make_model

CHUNK, WIDTH = 6, 1


class PerActionPolicy(nn.Module):
    """A small policy whose time enters each action: each action's velocity from the whole chunk, its own position,
    time and target time, and the observation."""

    def __init__(self, observation_dim: int = 2, hidden: int = 96) -> None:
        super().__init__()
        inputs = CHUNK * WIDTH + WIDTH + 2 * 8 + CHUNK + observation_dim
        self.net = nn.Sequential(nn.Linear(inputs, hidden), nn.SiLU(), nn.Linear(hidden, hidden), nn.SiLU())
        self.out = nn.Linear(hidden, WIDTH)

    def encode(self, observation: Tensor) -> Tensor:
        return observation

    def velocity_per_action(self, x_t: Tensor, t: Tensor, s: Tensor, context: Tensor) -> Tensor:
        batch = x_t.shape[0]
        features = [
            x_t.flatten(1)[:, None, :].expand(-1, CHUNK, -1),
            x_t,
            sinusoidal_features(t.reshape(-1), 8).reshape(batch, CHUNK, 8),
            sinusoidal_features(s.reshape(-1), 8).reshape(batch, CHUNK, 8),
            torch.eye(CHUNK)[None].expand(batch, -1, -1),
            context[:, None, :].expand(-1, CHUNK, -1),
        ]
        return self.out(self.net(torch.cat(features, dim=2)))

    def velocity(self, x_t: Tensor, t: Tensor, s: Tensor, context: Tensor) -> Tensor:
        return self.velocity_per_action(x_t, t[:, None].expand(-1, CHUNK), s[:, None].expand(-1, CHUNK), context)


class Recorder:
    """A PerActionTimes policy that records what it is given and answers ones."""

    def __init__(self) -> None:
        self.calls: list[tuple[Tensor, Tensor, Tensor]] = []

    def encode(self, observation: Tensor) -> Tensor:
        return observation

    def velocity_per_action(self, x_t: Tensor, t: Tensor, s: Tensor, context: Tensor) -> Tensor:
        self.calls.append((x_t.clone(), t.clone(), s.clone()))
        return torch.ones_like(x_t)


def test_each_pass_sees_the_known_actions_at_time_zero_and_leaves_them_where_they_are():
    recorder = Recorder()
    assert isinstance(recorder, PerActionTimes)
    known, mask = torch.full((2, 4, 3), 7.0), prefix_mask(torch.tensor([2, 0]), 4)
    assert mask.tolist() == [[True, True, False, False], [False] * 4]
    view = KnownPrefixPolicy(recorder, known, mask)
    context = view.encode(torch.zeros(2, 1))
    x, t, s = torch.zeros(2, 4, 3), torch.tensor([0.8, 0.6]), torch.tensor([0.0, 0.3])
    velocity = view.velocity(x, t, s, context)
    seen_x, seen_t, seen_s = recorder.calls[0]
    assert torch.equal(seen_x[0, :2], known[0, :2]) and torch.equal(seen_x[0, 2:], x[0, 2:])
    assert torch.equal(seen_x[1], x[1])
    assert torch.allclose(seen_t, torch.tensor([[0, 0, 0.8, 0.8], [0.6] * 4]))
    assert torch.allclose(seen_s, torch.tensor([[0, 0, 0, 0], [0.3] * 4]))
    assert velocity[0, :2].abs().sum() == 0 and torch.equal(velocity[0, 2:], torch.ones(2, 3))
    weights = view.action_weights(None)
    assert weights.shape == (2, 4, 1) and weights[..., 0].tolist() == [[0, 0, 1, 1], [1] * 4]


@pytest.mark.parametrize("mode", [SNAPFLOW_1, TEACHER_10, SamplingMode(3, jump=True)])
def test_a_continued_chunk_starts_with_the_previous_chunks_actions_exactly(mode):
    torch.manual_seed(0)
    policy, noise = PerActionPolicy(), torch.randn(3, CHUNK, WIDTH)
    previous = torch.randn(3, 4, WIDTH)
    chunk = sample_continuing(policy, torch.zeros(3, 2), noise, mode, previous, 2)
    assert torch.equal(chunk[:, :2], previous[:, :2])
    free = sample_continuing(policy, torch.zeros(3, 2), noise, mode, previous, 0)
    assert not torch.allclose(chunk[:, 2:], free[:, 2:]), "the known prefix conditions the rest"
    with pytest.raises(InvalidInputError, match="inference delay of 5"):
        sample_continuing(policy, torch.zeros(3, 2), noise, mode, previous, 5)


def test_a_policy_with_one_time_a_chunk_is_refused_by_name():
    with pytest.raises(InvalidInputError, match="takes one time a chunk"):
        KnownPrefixPolicy(make_model(), torch.zeros(1, 3, 2), torch.zeros(1, 3, dtype=torch.bool))


def test_the_setting_is_checked_and_wraps_only_when_asked():
    from snapflow.flow.time_sampling import UniformTimeSampler
    from snapflow.objective.known_prefix import KnownPrefixObjective

    assert not isinstance(DistillSettings().objective(UniformTimeSampler()), KnownPrefixObjective)
    wrapped = DistillSettings(rtc_max_delay=2).objective(UniformTimeSampler())
    assert isinstance(wrapped, KnownPrefixObjective) and wrapped.alpha == DistillSettings().alpha
    for bad in (-1, 1.5, True):
        with pytest.raises(InvalidInputError, match="rtc_max_delay"):
            DistillSettings(rtc_max_delay=bad)
    with pytest.raises(InvalidInputError, match="keeps a copy of the policy"):
        DistillSettings(method="consistency-distillation", rtc_max_delay=1)


def _bimodal(count: int, generator: torch.Generator) -> Tensor:
    """Chunks that hold +1 or -1 throughout, by a coin the observation does not show."""
    signs = torch.randint(0, 2, (count, 1, 1), generator=generator) * 2.0 - 1.0
    return signs.expand(-1, CHUNK, WIDTH) + 0.05 * torch.randn(count, CHUNK, WIDTH, generator=generator)


def _distil(settings: DistillSettings, steps: int = 1500) -> PerActionPolicy:
    from snapflow.flow.time_sampling import UniformTimeSampler

    torch.manual_seed(0)
    policy, generator = PerActionPolicy(), torch.Generator().manual_seed(1)
    objective = settings.objective(UniformTimeSampler())
    optimizer = torch.optim.Adam(policy.parameters(), lr=2e-3)
    for _ in range(steps):
        loss = objective(policy, torch.zeros(128, 2), _bimodal(128, generator), generator=generator).loss
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
    return policy


@pytest.mark.slow
def test_a_jump_trained_with_known_prefixes_continues_them_where_a_bare_jump_picks_by_its_noise():
    noise = torch.randn(400, CHUNK, WIDTH, generator=torch.Generator().manual_seed(9))
    previous = torch.cat([torch.ones(200, CHUNK, WIDTH), -torch.ones(200, CHUNK, WIDTH)])
    sign = previous[:, 0, 0]

    def agreement(policy: PerActionPolicy, delay: int) -> float:
        with torch.no_grad():
            chunk = sample_continuing(policy, torch.zeros(400, 2), noise, SNAPFLOW_1, previous, delay)
        return (chunk[:, -1, 0].sign() == sign).float().mean().item()

    trained = _distil(DistillSettings(consistency_weight=1.0, rtc_max_delay=2))
    assert agreement(trained, 2) > 0.95, "given its first two actions, the jump continues their mode"
    free = agreement(trained, 0)
    assert 0.2 < free < 0.8, f"with nothing known it still keeps both modes ({free:.2f})"
