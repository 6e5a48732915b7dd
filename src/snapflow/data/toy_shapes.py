"""The toy's conditional distributions by shape, each with exact samples and the mode every sample falls in.

``mixture`` is :class:`~snapflow.data.toy_mixture.ConditionalGaussianMixture` (modes evenly spaced on a circle);
``rings`` is :class:`ConditionalRings`, two concentric rings whose weights depend on the context: a multimodal toy
of another shape (its modes are curves, not points), kept out of tuning (:data:`snapflow.jobs.toy_config.SHAPES`). Each shape names the mode a sample is in,
or none (-1) where it lies off every mode, so that mode coverage can be counted
(:func:`snapflow.evaluation.distances.mode_shares`).
"""

from __future__ import annotations

import math
from collections.abc import Callable

import torch
from torch import Tensor

from snapflow.data.toy_mixture import ConditionalGaussianMixture, ContextWeightedModes

#: a sample further than this many mode standard deviations from every mode lies off them all
OFF_MODE_STDS = 4.0


class ConditionalRings(ContextWeightedModes):
    """p(a | c) = sum_k softmax(gain * W c)_k Ring(r_k): a uniform angle, the radius r_k + std * N(0, 1).

    The radii are ``radius`` * (1 + k) / ``num_modes`` (two rings of radii 1 and 2 by default); contexts are
    c ~ N(0, I) and ``W`` is fixed by ``seed``.
    """

    def __init__(
        self,
        num_modes: int = 2,
        context_dim: int = 4,
        radius: float = 2.0,
        mode_std: float = 0.08,
        weight_gain: float = 2.0,
        seed: int = 0,
    ) -> None:
        super().__init__(num_modes, context_dim, weight_gain, seed)
        self.radii = radius * torch.arange(1, num_modes + 1, dtype=torch.float32) / num_modes
        self.mode_std = mode_std

    def sample(self, context: Tensor, generator: torch.Generator | None = None) -> Tensor:
        """One exact sample a ~ p(a | c) per context row, shape (B, 2)."""
        modes = self.sample_modes(context, generator)
        angles = 2 * math.pi * torch.rand(len(modes), generator=generator)
        radii = self.radii[modes] + self.mode_std * torch.randn(len(modes), generator=generator)
        return radii[:, None] * torch.stack([angles.cos(), angles.sin()], dim=1)

    def mode_of(self, samples: Tensor) -> Tensor:
        """The ring each sample (N, 2) lies on: the nearest radius, or -1 beyond :data:`OFF_MODE_STDS` std of it."""
        gaps = (samples.norm(dim=-1, keepdim=True) - self.radii).abs()
        nearest = gaps.argmin(-1)
        return torch.where(gaps.gather(-1, nearest[:, None])[:, 0] > OFF_MODE_STDS * self.mode_std, -1, nearest)


def mixture_mode_of(mixture: ConditionalGaussianMixture, samples: Tensor) -> Tensor:
    """The Gaussian mode each sample (N, 2) of ``mixture`` lies in: the nearest mean, or -1 beyond
    :data:`OFF_MODE_STDS` std of it."""
    distances = torch.cdist(samples, mixture.means)
    nearest = distances.argmin(-1)
    return torch.where(distances.gather(-1, nearest[:, None])[:, 0] > OFF_MODE_STDS * mixture.mode_std, -1, nearest)


class ToyShape:
    """One toy distribution by name: exact samples, contexts, true mode weights and each sample's mode."""

    def __init__(self, name: str, num_modes: int, radius: float) -> None:
        if name not in _BUILDERS:
            raise ValueError(f"unknown toy shape {name!r}; choose one of {list(_BUILDERS)}")
        self.name = name
        self.distribution = _BUILDERS[name](num_modes, radius)
        self.context_dim = self.distribution.context_dim
        self.num_modes = len(self.distribution.logit_map)

    def sample_contexts(self, n: int, generator: torch.Generator | None = None) -> Tensor:
        return self.distribution.sample_contexts(n, generator)

    def sample(self, context: Tensor, generator: torch.Generator | None = None) -> Tensor:
        return self.distribution.sample(context, generator)

    def mode_weights(self, context: Tensor) -> Tensor:
        """The true share of each mode given each context (B, modes)."""
        return self.distribution.mode_weights(context)

    def mode_of(self, samples: Tensor) -> Tensor:
        """Each sample's mode index, -1 off every mode."""
        if isinstance(self.distribution, ConditionalRings):
            return self.distribution.mode_of(samples)
        return mixture_mode_of(self.distribution, samples)


# the toy's shapes (``snapflow.jobs.toy_config.SHAPES`` names them for the CLI): the mixture the recipes are tuned on
# (its mode count given), and the held-out rings (always two)
_BUILDERS: dict[str, Callable[[int, float], ConditionalGaussianMixture | ConditionalRings]] = {
    "mixture": lambda num_modes, radius: ConditionalGaussianMixture(num_modes=num_modes, radius=radius),
    "rings": lambda num_modes, radius: ConditionalRings(radius=radius),
}


__all__ = ["ConditionalRings", "OFF_MODE_STDS", "ToyShape", "mixture_mode_of"]
