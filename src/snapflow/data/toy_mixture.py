"""A conditional problem with a known answer: 2-D Gaussian mixtures whose mode weights depend on a context.

Exact samples are free, so every sampling mode can be scored by its energy distance to the data
(:func:`snapflow.evaluation.distances.energy_distance`).
"""

from __future__ import annotations

import math

import torch
from torch import Tensor


class ContextWeightedModes:
    """Mode weights that depend on a context: softmax(gain * W c), contexts c ~ N(0, I), ``W`` fixed by ``seed`` so
    that the distribution is the same on every machine. A toy shape adds where its modes lie and how to sample them."""

    def __init__(self, num_modes: int, context_dim: int, weight_gain: float, seed: int) -> None:
        self.num_modes = num_modes
        self.context_dim = context_dim
        self.logit_map = weight_gain * torch.randn(
            num_modes, context_dim, generator=torch.Generator().manual_seed(seed)
        )

    def mode_weights(self, context: Tensor) -> Tensor:
        return torch.softmax(context @ self.logit_map.T, dim=1)

    def sample_contexts(self, n: int, generator: torch.Generator | None = None) -> Tensor:
        return torch.randn(n, self.context_dim, generator=generator)

    def sample_modes(self, context: Tensor, generator: torch.Generator | None = None) -> Tensor:
        """One mode index per context row, drawn from its weights."""
        return torch.multinomial(self.mode_weights(context), 1, generator=generator).squeeze(1)


class ConditionalGaussianMixture(ContextWeightedModes):
    """p(a | c) = sum_k softmax(gain * W c)_k N(mu_k, std^2 I), modes evenly spaced on a circle.

    Contexts are c ~ N(0, I). ``W`` is fixed by ``seed``, so the distribution is the same on every machine.
    """

    def __init__(
        self,
        num_modes: int = 6,
        context_dim: int = 4,
        radius: float = 2.0,
        mode_std: float = 0.12,
        weight_gain: float = 2.0,
        seed: int = 0,
    ) -> None:
        super().__init__(num_modes, context_dim, weight_gain, seed)
        angles = torch.arange(num_modes, dtype=torch.float32) * (2 * math.pi / num_modes)
        self.means = radius * torch.stack([angles.cos(), angles.sin()], dim=1)
        self.mode_std = mode_std

    def sample(self, context: Tensor, generator: torch.Generator | None = None) -> Tensor:
        """One exact sample a ~ p(a | c) per context row, shape (B, 2)."""
        modes = self.sample_modes(context, generator)
        return self.means[modes] + self.mode_std * torch.randn(len(modes), 2, generator=generator)


__all__ = ["ConditionalGaussianMixture", "ContextWeightedModes"]
