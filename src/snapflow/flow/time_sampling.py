"""Training-time distributions for flow matching.

A time sampler is a callable ``(batch_size, *, device, generator) -> Tensor`` returning times in (0, 1].
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import torch
from torch import Tensor

from snapflow.errors import InvalidInputError


class TimeSampler(Protocol):
    """Draws one flow-matching time per sample."""

    def __call__(
        self, batch_size: int, *, device: torch.device | str = "cpu", generator: torch.Generator | None = None
    ) -> Tensor: ...


@dataclass(frozen=True)
class UniformTimeSampler:
    """t ~ U(0, 1): the textbook flow-matching choice, used by the built-in policies."""

    def __call__(
        self, batch_size: int, *, device: torch.device | str = "cpu", generator: torch.Generator | None = None
    ) -> Tensor:
        return torch.rand(batch_size, device=device, generator=generator)


@dataclass(frozen=True)
class BetaTimeSampler:
    """t = min_time + (1 - min_time) * Beta(concentration, 1): pi0, pi0.5 and SmolVLA use (1.5, 0.001).

    Beta(a, 1) has CDF u ** a, so it is sampled exactly by inverting the CDF, u ** (1 / a), which lets the
    caller's generator make the draw reproducible. With a > 1 the mass leans towards t = 1 (noisy end).
    """

    concentration: float = 1.5
    min_time: float = 0.001

    def __post_init__(self) -> None:
        if self.concentration <= 0:
            raise InvalidInputError(f"concentration must be positive, got {self.concentration}")
        if not 0 <= self.min_time < 1:
            raise InvalidInputError(f"min_time must be in [0, 1), got {self.min_time}")

    def __call__(
        self, batch_size: int, *, device: torch.device | str = "cpu", generator: torch.Generator | None = None
    ) -> Tensor:
        u = torch.rand(batch_size, device=device, generator=generator)
        return self.min_time + (1 - self.min_time) * u.pow(1 / self.concentration)


__all__ = ["TimeSampler", "UniformTimeSampler", "BetaTimeSampler"]
