"""Distances between sample sets, for problems whose data distribution can be sampled exactly, and how samples\nshare out over a distribution's modes."""

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


def mode_shares(modes: Tensor, num_modes: int) -> Tensor:
    """Per observation, the share of its samples in each mode: ``modes`` (C, N) holds each sample's mode index, -1
    for one off every mode; (C, num_modes + 1), the last column the share off every mode."""
    if modes.ndim != 2:
        raise ValueError(f"expected mode indices (observations, samples), got shape {tuple(modes.shape)}")
    columns = torch.where(modes < 0, num_modes, modes)
    counts = torch.zeros(modes.shape[0], num_modes + 1, dtype=torch.float64)
    counts.scatter_add_(1, columns, torch.ones_like(columns, dtype=torch.float64))
    return counts / modes.shape[1]


def coverage_error(shares: Tensor, weights: Tensor) -> Tensor:
    """Mean over observations of the total variation distance between sampled mode ``shares`` (C, K + 1, the last
    column off every mode, as :func:`mode_shares`) and the true mode ``weights`` (C, K): 0 when every mode has its
    share and no sample lies between modes, 1 when all lie in modes of no weight or off them."""
    if shares.shape != (weights.shape[0], weights.shape[1] + 1):
        raise ValueError(f"shares {tuple(shares.shape)} must have one column more than weights {tuple(weights.shape)}")
    truth = torch.cat([weights.double(), weights.new_zeros(weights.shape[0], 1, dtype=torch.float64)], dim=1)
    return 0.5 * (shares.double() - truth).abs().sum(1).mean()


__all__ = ["coverage_error", "energy_distance", "mode_shares"]
