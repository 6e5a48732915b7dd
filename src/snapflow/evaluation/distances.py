"""Distances between sample sets, for problems whose data distribution can be sampled exactly."""

from __future__ import annotations

import torch
from torch import Tensor


def _mean_within(samples: Tensor) -> Tensor:
    """E|X - X'| over distinct pairs only: the zero diagonal would bias small sets towards each other."""
    n = samples.shape[0]
    return torch.cdist(samples, samples).sum() / (n * (n - 1))


def energy_distance(x: Tensor, y: Tensor) -> Tensor:
    """Energy distance sqrt(2 E|X - Y| - E|X - X'| - E|Y - Y'|) between sample sets (N, D) and (M, D).

    Uses the unbiased (U-statistic) estimate of the squared distance, clamped at zero before the root, so
    two sample sets drawn from one distribution score close to zero rather than O(1 / sqrt(N)).
    """
    if x.ndim != 2 or y.ndim != 2 or x.shape[1] != y.shape[1]:
        raise ValueError(f"expected two sample sets (N, D) and (M, D), got {tuple(x.shape)} and {tuple(y.shape)}")
    if len(x) < 2 or len(y) < 2:
        raise ValueError("energy distance needs at least two samples in each set")
    x, y = x.double(), y.double()
    squared = 2 * torch.cdist(x, y).mean() - _mean_within(x) - _mean_within(y)
    return squared.clamp_min(0).sqrt()


__all__ = ["energy_distance"]
