"""Summary statistics of repeated measurements (seeds, runs) and of success counts."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

Z_95 = 1.959963984540054  # two-sided 95% normal quantile


def mean_std(values: list[float]) -> tuple[float, float]:
    """Mean and sample standard deviation (0 for a single value) of per-seed results."""
    return float(np.mean(values)), float(np.std(values, ddof=1)) if len(values) > 1 else 0.0


# two-sided 95% quantiles of Student's t with 1, 2, ..., 10 degrees of freedom
_T_95 = (12.706, 4.303, 3.182, 2.776, 2.571, 2.447, 2.365, 2.306, 2.262, 2.228)


def t_interval_95(values: Sequence[float]) -> tuple[float, float]:
    """Student's t 95% interval of the mean of a few per-seed results (beyond 10 degrees of freedom, its quantile by
    the first Cornish-Fisher term, within 0.01); a single value is its own interval."""
    if len(values) < 1:
        raise ValueError("an interval needs at least one value")
    mean, std = mean_std(list(values))
    freedom = len(values) - 1
    if not freedom:
        return mean, mean
    quantile = _T_95[freedom - 1] if freedom <= len(_T_95) else Z_95 + (Z_95**3 + Z_95) / (4 * freedom)
    half = quantile * std / math.sqrt(len(values))
    return mean - half, mean + half


def wilson_interval(successes: int, trials: int, z: float = Z_95) -> tuple[float, float]:
    """Wilson score interval of a success rate (95% by default): unlike the normal approximation, it stays inside
    [0, 1] and keeps its coverage near 0% and 100%, where robot success rates live."""
    if trials < 1 or not 0 <= successes <= trials:
        raise ValueError(f"a success count needs 0 <= successes <= trials and trials >= 1, got {successes}/{trials}")
    rate = successes / trials
    denominator = 1 + z**2 / trials
    centre = (rate + z**2 / (2 * trials)) / denominator
    half = z * math.sqrt(rate * (1 - rate) / trials + z**2 / (4 * trials**2)) / denominator
    # at 0 or all successes the bound is exactly 0 or 1 (rounding would leave the observed rate outside)
    return (0.0 if successes == 0 else centre - half), (1.0 if successes == trials else centre + half)


def paired_difference(
    values: Sequence[float], reference: Sequence[float], resamples: int = 10_000, seed: int = 0, level: float = 0.95
) -> tuple[float, float, float]:
    """Mean of ``values - reference`` over paired units (the same seed and task, so the same evaluation variations)
    and its percentile-bootstrap interval, resampling the units: (mean, low, high). Pairing removes what the two
    rows share (a hard task, a lucky seed), so it resolves differences the two rows' own intervals cannot."""
    differences = np.asarray(values, dtype=float) - np.asarray(reference, dtype=float)
    if differences.ndim != 1 or len(differences) < 1 or len(values) != len(reference):
        raise ValueError(f"paired values need equal, non-empty lengths, got {len(values)} and {len(reference)}")
    generator = np.random.default_rng(seed)
    means = differences[generator.integers(0, len(differences), (resamples, len(differences)))].mean(axis=1)
    tail = 100 * (1 - level) / 2
    low, high = np.percentile(means, [tail, 100 - tail])
    return float(differences.mean()), float(low), float(high)


__all__ = ["Z_95", "mean_std", "t_interval_95", "wilson_interval", "paired_difference"]
