"""Intervals for success rates and paired differences, against the formulas written out by hand."""

from __future__ import annotations

import math

import numpy as np
import pytest

from snapflow.reporting.statistics import mean_std, paired_difference, t_interval_95, wilson_interval


@pytest.mark.parametrize("successes, trials", [(8, 10), (0, 10), (10, 10), (187, 200), (1, 1)])
def test_wilson_interval_is_the_score_interval_written_out(successes, trials):
    z, p, n = 1.959963984540054, successes / trials, trials
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z / (1 + z * z / n) * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n))
    low, high = wilson_interval(successes, trials)
    assert (low, high) == pytest.approx((max(centre - half, 0), min(centre + half, 1)))
    assert 0 <= low <= p <= high <= 1


def test_wilson_interval_matches_a_published_value_and_narrows_with_episodes():
    assert wilson_interval(8, 10) == pytest.approx((0.4902, 0.9433), abs=1e-4)  # Wilson (1927) / textbook value
    widths = [np.subtract(*wilson_interval(9 * n // 10, n)[::-1]) for n in (10, 100, 1000)]
    assert widths[0] > widths[1] > widths[2] > 0


@pytest.mark.parametrize("successes, trials", [(-1, 10), (11, 10), (0, 0)])
def test_impossible_counts_are_refused(successes, trials):
    with pytest.raises(ValueError, match="success count"):
        wilson_interval(successes, trials)


def test_a_paired_difference_sees_a_shift_the_rows_own_spread_hides():
    """Cells that vary a lot (hard and easy tasks) but differ by exactly +5 points: the paired interval is [5, 5]
    although each row alone spans 0-100."""
    reference = [0.0, 100.0, 40.0, 90.0, 10.0, 60.0]
    shifted = [value + 5 for value in reference]
    assert paired_difference(shifted, reference) == pytest.approx((5.0, 5.0, 5.0))
    assert paired_difference(reference, reference) == (0.0, 0.0, 0.0)


def test_a_paired_difference_is_the_mean_difference_with_a_bootstrap_interval_around_it():
    generator = np.random.default_rng(1)
    reference = generator.uniform(0, 100, 30)
    values = reference + generator.normal(-3, 4, 30)
    mean, low, high = paired_difference(values, reference)
    assert mean == pytest.approx(np.mean(values - reference))
    standard_error = np.std(values - reference, ddof=1) / np.sqrt(30)
    assert low < mean < high and (high - low) == pytest.approx(2 * 1.96 * standard_error, rel=0.2)
    assert paired_difference(values, reference) == (mean, low, high), "seeded: the same interval every time"
    with pytest.raises(ValueError, match="equal, non-empty"):
        paired_difference([1.0, 2.0], [1.0])


def test_mean_std_is_the_sample_standard_deviation():
    assert mean_std([1.0, 2.0, 3.0]) == pytest.approx((2.0, 1.0)) and mean_std([4.0]) == (4.0, 0.0)


def test_t_interval_is_the_mean_plus_minus_the_t_quantile_times_the_standard_error():
    """Three seeds: 2 degrees of freedom, quantile 4.303; a single value is its own interval."""
    low, high = t_interval_95([1.0, 2.0, 3.0])
    assert (low, high) == pytest.approx((2 - 4.303 / math.sqrt(3), 2 + 4.303 / math.sqrt(3)))
    assert t_interval_95([0.7]) == (0.7, 0.7)
    # beyond the table the approximation is within 0.01 of t's quantile (2.042 at 30 degrees of freedom)
    values = [float(v) for v in range(31)]
    half = (t_interval_95(values)[1] - t_interval_95(values)[0]) / 2
    assert half / (np.std(values, ddof=1) / math.sqrt(31)) == pytest.approx(2.042, abs=0.01)
