"""Energy distance against a hand computation and its basic properties."""

from __future__ import annotations

import math

import pytest
import torch

from snapflow.evaluation.distances import coverage_error, energy_distance, mode_shares


def test_energy_distance_by_hand():
    """Two points against two points, with the within-set means over distinct pairs only."""
    x = torch.tensor([[0.0], [1.0]])
    y = torch.tensor([[2.0], [4.0]])
    # E|X-Y| = (2 + 4 + 1 + 3) / 4 = 2.5, E|X-X'| = 1, E|Y-Y'| = 2 over distinct pairs
    assert energy_distance(x, y).item() == pytest.approx(math.sqrt(2 * 2.5 - 1 - 2))


def test_energy_distance_is_small_for_one_distribution_and_grows_with_a_shift():
    """Two draws of one distribution score near zero (a set against itself exactly zero), and the distance grows
    with a shift of one of them."""
    generator = torch.Generator().manual_seed(0)
    x, y = torch.randn(800, 2, generator=generator), torch.randn(800, 2, generator=generator)
    same = energy_distance(x, y).item()
    shifted = [energy_distance(x, y + torch.tensor([shift, 0.0])).item() for shift in (0.5, 1.0, 2.0)]
    assert same < 0.1
    assert same < shifted[0] < shifted[1] < shifted[2]
    assert energy_distance(x, x).item() == 0.0


def test_energy_distance_rejects_bad_shapes():
    """Sets of different widths, or of fewer than two samples, are refused by name."""
    with pytest.raises(ValueError, match="sample sets"):
        energy_distance(torch.zeros(5, 2), torch.zeros(5, 3))
    with pytest.raises(ValueError, match="two samples"):
        energy_distance(torch.zeros(1, 2), torch.zeros(5, 2))


def test_mode_shares_and_coverage_error_by_hand():
    """Two contexts of four samples over two modes (-1: off every mode): shares per context, the last column off
    every mode; the coverage error is the mean total variation to the true weights, with zero truth off the modes."""
    modes = torch.tensor([[0, 0, 1, -1], [1, 1, 1, 1]])
    shares = mode_shares(modes, 2)
    assert torch.equal(shares, torch.tensor([[0.5, 0.25, 0.25], [0.0, 1.0, 0.0]], dtype=torch.float64))
    weights = torch.tensor([[0.5, 0.5], [0.5, 0.5]])
    # context 0: |0.5 - 0.5| + |0.25 - 0.5| + |0.25 - 0| = 0.5 -> 0.25; context 1: 0.5 + 0.5 -> 0.5
    assert coverage_error(shares, weights).item() == pytest.approx((0.25 + 0.5) / 2)
    assert coverage_error(torch.tensor([[0.5, 0.5, 0.0]]), torch.tensor([[0.5, 0.5]])).item() == 0.0
    with pytest.raises(ValueError, match="one column more"):
        coverage_error(shares, torch.ones(2, 3))
