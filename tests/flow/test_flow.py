"""The flow-matching conventions: path, samplers, Euler solver and sampling modes."""

from __future__ import annotations

import pytest
import torch

from snapflow.flow import (
    NAIVE_1,
    SNAPFLOW_1,
    TEACHER_10,
    Beta22TimeSampler,
    BetaTimeSampler,
    SamplingMode,
    ShiftedTimeSampler,
    UniformTimeSampler,
    conditional_velocity,
    euler_sample,
    euler_step,
    interpolate,
    sample_actions,
    shifted,
)
from tests.helpers import RecordingPolicy


def test_path_endpoints_and_velocity():
    """x_t runs from the data at t = 0 to the noise at t = 1 on a straight line whose velocity is eps - a."""
    actions, noise = torch.randn(4, 3, 2), torch.randn(4, 3, 2)
    assert torch.equal(interpolate(actions, noise, torch.zeros(4)), actions)
    assert torch.equal(interpolate(actions, noise, torch.ones(4)), noise)
    t = torch.tensor([0.1, 0.4, 0.5, 0.9])
    x_t = interpolate(actions, noise, t)
    expected = torch.stack([(1 - t[i]) * actions[i] + t[i] * noise[i] for i in range(4)])
    assert torch.allclose(x_t, expected)
    # d x_t / d t along the path is eps - a
    dt = 1e-3
    finite_difference = (interpolate(actions, noise, t + dt) - x_t) / dt
    assert torch.allclose(finite_difference, conditional_velocity(actions, noise), atol=1e-3)


def test_path_rejects_mismatched_shapes():
    """Actions and noise of different shapes, or a time per sample of the wrong length, are named."""
    with pytest.raises(ValueError, match="differ in shape"):
        interpolate(torch.zeros(2, 3), torch.zeros(2, 4), torch.zeros(2))
    with pytest.raises(ValueError, match="time must have shape"):
        interpolate(torch.zeros(2, 3), torch.zeros(2, 3), torch.zeros(3))


def test_beta_time_sampler_matches_pi0_distribution():
    """pi0's Beta(1.5, 1) times, scaled into [0.001, 1], match their exact CDF and are reproducible by generator."""
    sampler = BetaTimeSampler()
    t = sampler(200_000, generator=torch.Generator().manual_seed(0))
    assert t.min() >= 0.001 and t.max() <= 1.0
    # Beta(1.5, 1) * 0.999 + 0.001 has CDF ((x - 0.001) / 0.999) ** 1.5
    grid = torch.linspace(0.01, 0.99, 50)
    empirical = (t[None, :] <= grid[:, None]).double().mean(dim=1)
    exact = ((grid - 0.001) / 0.999).double() ** 1.5
    assert (empirical - exact).abs().max() < 0.005
    draws = [sampler(8, generator=torch.Generator().manual_seed(3)) for _ in range(2)]
    assert torch.equal(draws[0], draws[1])
    with pytest.raises(ValueError, match="concentration"):
        BetaTimeSampler(concentration=0)


def test_beta22_time_sampler_is_evo1s_clamped_beta_two_two():
    """EVO1's Beta(2, 2) times clamped into [0.02, 0.98]: the CDF 3x^2 - 2x^3 inside, the clamped tails' mass
    F(0.02) = 0.001184 at each bound, and the median of three uniforms drawn from the caller's generator."""
    sampler = Beta22TimeSampler()
    t = sampler(400_000, generator=torch.Generator().manual_seed(0))
    assert t.min() == 0.02 and t.max() == 0.98
    grid = torch.linspace(0.05, 0.95, 19).double()
    empirical = (t[None, :] <= grid[:, None].float()).double().mean(dim=1)
    assert (empirical - (3 * grid**2 - 2 * grid**3)).abs().max() < 0.004
    tail = 3 * 0.02**2 - 2 * 0.02**3
    assert (
        abs((t == 0.02).double().mean().item() - tail) < 4e-4 and abs((t == 0.98).double().mean().item() - tail) < 4e-4
    )
    u = torch.rand(5, 3, generator=torch.Generator().manual_seed(3))  # by hand: the middle of each row's three
    middle = u.sort(dim=1).values[:, 1].clamp(0.02, 0.98)
    assert torch.equal(sampler(5, generator=torch.Generator().manual_seed(3)), middle)
    with pytest.raises(ValueError, match="min_time < max_time"):
        Beta22TimeSampler(0.5, 0.5)


def test_uniform_time_sampler():
    """U(0, 1) times: in range with mean 1/2."""
    t = UniformTimeSampler()(100_000, generator=torch.Generator().manual_seed(0))
    assert 0 <= t.min() and t.max() < 1
    assert abs(t.mean().item() - 0.5) < 0.005


def test_shifted_times_follow_the_shift_written_out_by_hand():
    """s t / (1 + (s - 1) t) at s = 4, by hand: 0.5 -> 2 / 2.5 = 0.8, 0.25 -> 1 / 1.75, the ends stay."""

    class Fixed:
        def __call__(self, batch_size, *, device="cpu", generator=None):
            return torch.tensor([0.0, 0.25, 0.5, 1.0])

    times = ShiftedTimeSampler(Fixed(), 4.0)(4)
    assert torch.allclose(times, torch.tensor([0.0, 1 / 1.75, 0.8, 1.0]))
    assert shifted(Fixed(), 2.0)(4)[2].item() == pytest.approx(2 / 3)


def test_shifting_pi0s_times_by_four_gives_the_high_noise_distribution():
    """T' = 4T / (1 + 3T) with T ~ pi0's times has CDF F(x / (4 - 3x)), F that of T: its median moves from 0.63 to
    0.87; the same generator gives the same draws, and shift 1 is the sampler itself (its draws unchanged)."""
    base = BetaTimeSampler()
    sampler = shifted(base, 4.0)
    t = sampler(200_000, generator=torch.Generator().manual_seed(0))
    assert t.min() > 0 and t.max() <= 1.0
    grid = torch.linspace(0.05, 0.95, 19).double()
    empirical = (t[None, :] <= grid[:, None]).double().mean(dim=1)
    exact = (((grid / (4 - 3 * grid)) - 0.001) / 0.999).clamp(min=0) ** 1.5
    assert (empirical - exact).abs().max() < 0.005
    median = 0.001 + 0.999 * 0.5 ** (2 / 3)  # pi0's, where x ** 1.5 = 1 / 2
    assert t.median().item() == pytest.approx(4 * median / (1 + 3 * median), abs=0.005)
    draws = [sampler(8, generator=torch.Generator().manual_seed(3)) for _ in range(2)]
    assert torch.equal(draws[0], draws[1])
    assert shifted(base, 1.0) is base
    with pytest.raises(ValueError, match="positive"):
        ShiftedTimeSampler(base, 0.0)


def test_sampling_mode_names_round_trip():
    """Mode names parse (with the bare defaults), canonical names round-trip, and malformed names are refused. A bare
    ``teacher`` is the policy's own number of steps, resolved by the policy, and samples nothing unresolved."""
    assert SamplingMode.parse("teacher-10") == TEACHER_10
    own = SamplingMode.parse("teacher")
    assert (own.name, own.resolved, own.num_steps) == ("teacher", False, None)
    assert own.with_own_steps(4) == SamplingMode(4, jump=False) and TEACHER_10.with_own_steps(4) == TEACHER_10
    with pytest.raises(ValueError, match="own number of steps"):
        euler_sample(lambda x, t, s: x, torch.zeros(1, 2), own)
    assert SamplingMode.parse("naive") == NAIVE_1 == SamplingMode.parse("teacher-1")
    assert SamplingMode.parse("snapflow") == SNAPFLOW_1
    assert SamplingMode.parse("SnapFlow-2") == SamplingMode(2, jump=True)
    for mode in (TEACHER_10, NAIVE_1, SNAPFLOW_1, SamplingMode(4, jump=True), own):
        assert SamplingMode.parse(mode.name) == mode
    for bad, message in (
        ("fast", "unknown sampling mode 'fast'"),
        ("teacher-0", "takes no step"),
        ("naive-2", "naive sampling is one step"),
        ("snapflow--1", "unknown sampling mode"),
    ):
        with pytest.raises(ValueError, match=message):
            SamplingMode.parse(bad)
    with pytest.raises(ValueError, match="num_steps must be at least 1, got 0"):
        SamplingMode(0, jump=True)


def test_euler_is_exact_for_a_constant_velocity_field():
    """On one straight path the velocity is constant, so any number of Euler steps lands on the data."""
    actions, noise = torch.randn(3, 4, 2), torch.randn(3, 4, 2)
    for steps in (1, 2, 10):
        result = euler_sample(lambda x, t, s: noise - actions, noise, SamplingMode(steps, jump=False))
        assert torch.allclose(result, actions, atol=1e-6)


def test_euler_step_moves_by_the_time_difference_per_sample():
    """x + (t_next - t) * v, with a time difference per sample broadcast over the chunk."""
    x, velocity = torch.randn(2, 3, 2), torch.randn(2, 3, 2)
    t, t_next = torch.tensor([1.0, 0.5]), torch.tensor([0.75, 0.0])
    moved = euler_step(x, velocity, t, t_next)
    assert torch.allclose(moved[0], x[0] - 0.25 * velocity[0]) and torch.allclose(moved[1], x[1] - 0.5 * velocity[1])


def test_euler_follows_a_time_dependent_field_by_hand():
    """v(x, t) = x: two Euler steps of dt = -1/2 give x * (1 - 1/2) ** 2."""
    noise = torch.randn(2, 1, 3)
    result = euler_sample(lambda x, t, s: x, noise, SamplingMode(2, jump=False))
    assert torch.allclose(result, noise * 0.25)


def test_each_mode_asks_for_the_right_target_time(student, batch):
    """The teacher asks for s = t at each grid time, naive for s = t = 1, SnapFlow-N for s = the next grid time;
    the prefix is encoded once and sampling builds no graph."""
    observation, _ = batch
    noise = torch.randn(6, 3, 2)
    for mode, expected in [
        (TEACHER_10, [(1 - i / 10, 1 - i / 10) for i in range(10)]),
        (NAIVE_1, [(1.0, 1.0)]),
        (SNAPFLOW_1, [(1.0, 0.0)]),
        (SamplingMode(2, jump=True), [(1.0, 0.5), (0.5, 0.0)]),
    ]:
        recorder = RecordingPolicy(student)
        result = sample_actions(recorder, observation, noise, mode)
        assert recorder.encodes == 1, "the prefix must be encoded once per chunk"
        asked = [(c.t[0].item(), c.s[0].item()) for c in recorder.calls]
        assert len(asked) == len(expected)
        assert torch.allclose(torch.tensor(asked), torch.tensor(expected, dtype=torch.float32))
        assert result.shape == noise.shape and not result.requires_grad


def test_snapflow_one_step_is_x1_minus_the_jump_velocity(student, batch):
    """SnapFlow 1-NFE is x_1 - F(x_1, t=1, s=0); naive 1-NFE is x_1 - F(x_1, t=1, s=1)."""
    observation, _ = batch
    noise = torch.randn(6, 3, 2)
    context = student.encode(observation)
    by_hand = noise - student.velocity(noise, torch.ones(6), torch.zeros(6), context)
    assert torch.allclose(sample_actions(student, observation, noise, SNAPFLOW_1), by_hand)
    naive_by_hand = noise - student.velocity(noise, torch.ones(6), torch.ones(6), context)
    assert torch.allclose(sample_actions(student, observation, noise, NAIVE_1), naive_by_hand)
