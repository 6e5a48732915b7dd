"""Energy distance against a hand computation and its basic properties."""

from __future__ import annotations

import math

import pytest
import torch

from snapflow.evaluation.distances import energy_distance


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
