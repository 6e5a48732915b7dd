"""The toy's shapes: the held-out rings sample their context-dependent weights on their radii, and each shape names
the mode a sample lies in, or none off them all."""

from __future__ import annotations

import pytest
import torch

from snapflow.data.toy_shapes import OFF_MODE_STDS, ConditionalRings, ToyShape
from snapflow.jobs.toy_config import SHAPES, ToyConfig


def test_rings_sample_their_weights_on_their_radii_at_uniform_angles():
    rings = ConditionalRings()
    assert torch.equal(rings.radii, torch.tensor([1.0, 2.0]))
    context = rings.sample_contexts(1, torch.Generator().manual_seed(0)).repeat(20_000, 1)
    samples = rings.sample(context, torch.Generator().manual_seed(1))
    modes = rings.mode_of(samples)
    frequencies = torch.bincount(modes[modes >= 0], minlength=2).float() / len(samples)
    assert torch.allclose(frequencies, rings.mode_weights(context[:1])[0], atol=0.015)
    assert (modes >= 0).float().mean() > 0.999, "exact samples lie on their rings"
    angles = torch.atan2(samples[:, 1], samples[:, 0])
    quadrants = torch.bincount(((angles + torch.pi) // (torch.pi / 2)).long().clamp(max=3), minlength=4) / len(samples)
    assert torch.allclose(quadrants, torch.full((4,), 0.25), atol=0.015)


def test_each_shape_names_the_nearest_mode_or_none_off_them_all():
    """By hand: the mixture's modes sit at radius 2 on angles k * 60 degrees; the rings at radii 1 and 2."""
    mixture = ToyShape("mixture", 6, 2.0)
    on_mode_1 = 2.0 * torch.tensor([0.5, 3**0.5 / 2])
    between = torch.tensor([2.0, 0.0]).lerp(on_mode_1, 0.5)
    near = on_mode_1 + torch.tensor([(OFF_MODE_STDS - 1) * 0.12, 0.0])
    assert mixture.mode_of(torch.stack([on_mode_1, between, near])).tolist() == [1, -1, 1]
    rings = ToyShape("rings", 2, 2.0)
    points = torch.tensor([[0.0, 1.02], [-1.5, 0.0], [0.0, -2.1], [0.0, 0.0]])
    assert rings.mode_of(points).tolist() == [0, -1, 1, -1]
    assert (mixture.num_modes, rings.num_modes) == (6, 2)


def test_the_shapes_are_named_once_for_the_cli_and_an_unknown_one_is_refused():
    for name in SHAPES:
        assert ToyShape(name, 6, 2.0).name == name
    with pytest.raises(ValueError, match="unknown toy shape"):
        ToyConfig(shape="square")
    assert "shape" not in ToyConfig().record(), "the mixture's runs keep the cache key they were recorded under"
    assert ToyConfig(shape="rings").record()["shape"] == "rings"
