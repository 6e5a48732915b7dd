"""Real-time chunking in plain torch: LeRobot's prefix weights and guided Euler step to the bit (against LeRobot's
own RTCProcessor where it is installed), by hand, and a chunk continuing a previous one under each kind."""

from __future__ import annotations

import pytest
import torch
from torch import Tensor

from snapflow.errors import InvalidInputError
from snapflow.flow.modes import NAIVE_1, SNAPFLOW_1, TEACHER_10, SamplingMode
from snapflow.flow.realtime import (
    RealTimeChunking,
    continuation_weights,
    guided_euler,
    padded_previous,
    prefix_weights,
    sample_chunk_continuing,
)
from snapflow.flow.solver import euler_sample
from tests.flow.test_known_prefix import CHUNK, WIDTH, PerActionPolicy
from tests.helpers import make_model


def _velocity(x: Tensor, t: Tensor, s: Tensor) -> Tensor:
    """A nonlinear field of x and t, so that a steered step differs from a plain one."""
    return torch.tanh(1.5 * x.flip(1)) * t[:, None, None] - 0.3 * x + s[:, None, None]


def test_prefix_weights_by_hand():
    assert torch.allclose(prefix_weights(2, 6, 8), torch.tensor([1, 1, 0.8, 0.6, 0.4, 0.2, 0, 0]))
    assert prefix_weights(2, 6, 8, "zeros").tolist() == [1, 1, 0, 0, 0, 0, 0, 0]
    assert prefix_weights(0, 4, 5).tolist() == pytest.approx([0.8, 0.6, 0.4, 0.2, 0.0])
    assert prefix_weights(5, 3, 6).tolist() == [1, 1, 1, 0, 0, 0], "the delay stops at the horizon"


def test_the_settings_are_checked_and_guidance_of_a_jump_is_refused():
    for bad in (
        dict(delay=-1),
        dict(delay=1.5),
        dict(delay=2, kind="steer"),
        dict(delay=2, schedule="exp"),
        dict(delay=2, execution_horizon=0),
        dict(delay=2, jump_weight=1.5),
        dict(delay=2, max_guidance_weight=0.0),
    ):
        with pytest.raises(InvalidInputError):
            RealTimeChunking(**bad)
    with pytest.raises(InvalidInputError, match="steers Euler steps; snapflow-1 jumps"):
        RealTimeChunking(2, "guided").check_mode(SNAPFLOW_1)
    RealTimeChunking(2, "guided").check_mode(NAIVE_1)
    assert RealTimeChunking(2).for_mode(SNAPFLOW_1).kind == "inpaint"
    assert RealTimeChunking(2).for_mode(TEACHER_10).kind == "guided"
    assert RealTimeChunking(2, "trained").for_mode(SNAPFLOW_1).kind == "trained"


def test_guidance_with_zero_weights_is_the_plain_euler_chunk_and_pulls_toward_the_prefix_otherwise():
    noise, previous = torch.randn(3, 8, 2), torch.randn(3, 8, 2)
    plain = euler_sample(_velocity, noise, TEACHER_10)
    unweighted = guided_euler(_velocity, noise, 10, previous, torch.zeros(1, 8, 1), 10.0)
    assert torch.allclose(unweighted, plain, atol=1e-6)
    weights = prefix_weights(2, 6, 8)[None, :, None]
    guided = guided_euler(_velocity, noise, 10, previous, weights, 10.0)
    assert (guided[:, :2] - previous[:, :2]).abs().mean() < 0.5 * (plain[:, :2] - previous[:, :2]).abs().mean()
    assert not torch.equal(guided[:, 6:], plain[:, 6:]), "the field carries the pull to the unweighted actions"


@pytest.mark.parametrize("mode", [SNAPFLOW_1, SamplingMode(2, jump=True), NAIVE_1])
@pytest.mark.parametrize("kind", ["inpaint", "trained"])
def test_a_continued_chunk_starts_with_the_previous_chunks_actions(kind, mode):
    torch.manual_seed(0)
    policy, noise, previous = PerActionPolicy(), torch.randn(3, CHUNK, WIDTH), torch.randn(3, 4, WIDTH)
    rtc = RealTimeChunking(2, kind, execution_horizon=4)
    context = torch.zeros(3, 2)
    chunk = sample_chunk_continuing(policy, context, noise, mode, previous, rtc)
    assert (
        torch.equal(chunk[:, :2], previous[:, :2])
        if kind == "trained"
        else torch.allclose(chunk[:, :2], previous[:, :2], atol=1e-6)
    )
    free = euler_sample(lambda x, t, s: policy.velocity(x, t, s, context), noise, mode)
    weights = continuation_weights(rtc, previous, noise)
    assert weights[0, :, 0].tolist() == pytest.approx([1, 1, 2 / 3, 1 / 3, 0, 0])
    if kind == "inpaint":
        expected = free + weights * (padded_previous(previous, noise) - free)
        assert torch.allclose(chunk, expected, atol=1e-6)
    assert torch.allclose(chunk[:, 4:], free[:, 4:]) == (kind == "inpaint"), "past the horizon: the chunk's own"


def test_trained_needs_a_policy_with_a_time_per_action_and_the_delay_must_fit():
    from snapflow.nn import SnapFlowPolicy

    student = SnapFlowPolicy(make_model())
    noise, previous = torch.randn(2, 3, 2), torch.randn(2, 3, 2)
    with pytest.raises(InvalidInputError, match="MLPFlowModel takes one time a chunk"):
        sample_chunk_continuing(student, torch.zeros(2, 4), noise, SNAPFLOW_1, previous, RealTimeChunking(1, "trained"))
    with pytest.raises(InvalidInputError, match="inference delay of 4"):
        sample_chunk_continuing(student, torch.zeros(2, 4), noise, NAIVE_1, previous, RealTimeChunking(4, "inpaint"))


LEROBOT_CASES = [(0, 4, 8), (2, 6, 8), (3, 3, 8), (4, 10, 8), (5, 3, 6), (1, 8, 8), (2, 5, 16)]


@pytest.mark.parametrize("schedule", ["linear", "zeros"])
def test_the_weights_are_lerobots(schedule):
    processor = _lerobot_processor(schedule, 10.0)
    for delay, horizon, total in LEROBOT_CASES:
        ours, theirs = (
            prefix_weights(delay, horizon, total, schedule),
            processor.get_prefix_weights(delay, horizon, total),
        )
        assert ours.dtype == theirs.dtype and torch.equal(ours, theirs), (delay, horizon, total)


@pytest.mark.parametrize("schedule", ["linear", "zeros"])
@pytest.mark.parametrize(
    ("steps", "leftover", "delay", "horizon", "max_weight"), [(10, 5, 2, 4, 10.0), (4, 8, 3, 8, 2.5)]
)
def test_the_guided_euler_chunk_is_lerobots(schedule, steps, leftover, delay, horizon, max_weight):
    processor = _lerobot_processor(schedule, max_weight)
    generator = torch.Generator().manual_seed(3)
    noise, previous = torch.randn(3, 8, 2, generator=generator), torch.randn(3, leftover, 2, generator=generator)
    x, dt = noise, -1.0 / steps
    for step in range(steps):  # LeRobot's own guided sampler
        time = 1.0 + step * dt
        t = torch.tensor(time, dtype=torch.float32).expand(3)
        x = x + dt * processor.denoise_step(x, previous, delay, time, lambda x_t, t=t: _velocity(x_t, t, t), horizon)
    rtc = RealTimeChunking(delay, "guided", horizon, schedule, max_weight)
    ours = guided_euler(
        _velocity,
        noise,
        steps,
        padded_previous(previous, noise),
        continuation_weights(rtc, previous, noise),
        max_weight,
    )
    assert torch.allclose(ours, x, atol=1e-6, rtol=0), (ours - x).abs().max()
    assert not torch.allclose(ours, euler_sample(_velocity, noise, SamplingMode(steps, jump=False)), atol=1e-3)


def _lerobot_processor(schedule: str, max_guidance_weight: float):
    pytest.importorskip("lerobot")
    from lerobot.configs.types import RTCAttentionSchedule
    from lerobot.policies.rtc.configuration_rtc import RTCConfig
    from lerobot.policies.rtc.modeling_rtc import RTCProcessor

    return RTCProcessor(
        RTCConfig(
            enabled=True,
            prefix_attention_schedule=RTCAttentionSchedule[schedule.upper()],
            max_guidance_weight=max_guidance_weight,
        )
    )
