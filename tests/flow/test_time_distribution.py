"""The named time distributions of a built-in teacher: each written one way, each mistake refused in one line, and
each drawn as its formula says, against the math written out here."""

from __future__ import annotations

import pytest
import torch

from snapflow.errors import InvalidInputError
from snapflow.flow.time_distribution import TIME_DISTRIBUTIONS, canonical_time_distribution, parse_time_distribution
from snapflow.flow.time_sampling import time_sampler_for


def _uniforms(count: int, seed: int = 0) -> torch.Tensor:
    return torch.rand(count, generator=torch.Generator().manual_seed(seed))


def _beta(u: torch.Tensor, a: float) -> torch.Tensor:
    """0.001 + 0.999 Beta(a, 1) from uniforms: Beta(a, 1)'s CDF is x ** a, so its inverse is u ** (1 / a)."""
    return 0.001 + 0.999 * u ** (1 / a)


def _draws(distribution: str, count: int, seed: int = 0) -> torch.Tensor:
    return time_sampler_for(distribution)(count, generator=torch.Generator().manual_seed(seed))


@pytest.mark.parametrize(
    ("given", "written"),
    [
        ("uniform", "uniform"),
        (" beta:1.50", "beta:1.5"),
        ("beta:2", "beta:2"),
        ("shift:4.0", "shift:4"),
        ("shift:0.5", "shift:0.5"),
    ],
)
def test_a_distribution_is_written_one_way(given, written):
    assert canonical_time_distribution(given) == written


@pytest.mark.parametrize(
    ("given", "message"),
    [
        ("gamma:2", "unknown time distribution 'gamma:2'; choose one of uniform, beta:A, shift:S"),
        ("beta", "beta:A needs a number A, got 'beta'"),
        ("beta:x", "beta:A needs a number A, got 'beta:x'"),
        ("beta:0", "beta:A takes a positive, finite A, got 'beta:0'"),
        ("shift:-4", "shift:S takes a positive, finite S, got 'shift:-4'"),
        ("shift:inf", "shift:S takes a positive, finite S"),
        ("uniform:1", "the time distribution 'uniform' takes no value"),
        (1.5, "a time distribution is written as text"),
    ],
)
def test_a_mistaken_distribution_is_refused_in_one_line(given, message):
    with pytest.raises(InvalidInputError) as error:
        parse_time_distribution(given)
    assert message in str(error.value) and "\n" not in str(error.value)


def test_every_declared_distribution_has_its_sampler():
    for name, kind in TIME_DISTRIBUTIONS.items():
        distribution = name if kind.parameter is None else f"{name}:2"
        times = _draws(distribution, 1000)
        assert times.shape == (1000,) and bool(((times >= 0) & (times <= 1)).all()), distribution


def test_each_distribution_draws_its_formula_from_the_callers_generator():
    u = _uniforms(4096)
    torch.testing.assert_close(_draws("uniform", 4096), u, rtol=0, atol=0)
    torch.testing.assert_close(_draws("beta:1.5", 4096), _beta(u, 1.5))
    torch.testing.assert_close(_draws("beta:3", 4096), _beta(u, 3.0))
    base = _beta(u, 1.5)  # the paper's base, pi0's Beta(1.5, 1), shifted: t -> s t / (1 + (s - 1) t)
    torch.testing.assert_close(_draws("shift:4", 4096), 4 * base / (1 + 3 * base))
    torch.testing.assert_close(_draws("shift:1", 4096), base, rtol=0, atol=0)  # no shift: the base itself


def test_the_draws_follow_each_distributions_cdf():
    """Against the closed-form CDFs at a few points (200,000 draws: the empirical CDF within 0.005)."""
    count = 200_000
    for point in (0.2, 0.5, 0.8, 0.95):
        assert abs((_draws("uniform", count, seed=1) <= point).double().mean().item() - point) < 0.005
        beta = ((point - 0.001) / 0.999) ** 1.5  # P(0.001 + 0.999 X <= t) with P(X <= x) = x ** 1.5
        assert abs((_draws("beta:1.5", count, seed=2) <= point).double().mean().item() - beta) < 0.005
        # the shift is increasing: P(shifted <= t) = P(base <= its inverse, t / (s - (s - 1) t))
        unshifted = point / (4 - 3 * point)
        shifted = ((unshifted - 0.001) / 0.999) ** 1.5
        assert abs((_draws("shift:4", count, seed=3) <= point).double().mean().item() - shifted) < 0.005
    # leaning toward noise (t = 1): the mean rises from uniform's 1/2 through Beta(1.5, 1)'s 0.6 to the shift's
    means = [_draws(name, count, seed=4).mean().item() for name in ("uniform", "beta:1.5", "shift:4")]
    assert abs(means[0] - 0.5) < 0.005 and abs(means[1] - (0.001 + 0.999 * 0.6)) < 0.005 and means[2] > 0.8
