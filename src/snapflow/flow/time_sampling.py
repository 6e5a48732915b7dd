"""Training-time distributions for flow matching.

A time sampler is a callable ``(batch_size, *, device, generator) -> Tensor`` returning times in (0, 1].
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol

import torch
from torch import Tensor

from snapflow.errors import InvalidInputError
from snapflow.flow.time_distribution import parse_time_distribution


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


@dataclass(frozen=True)
class Beta22TimeSampler:
    """t ~ Beta(2, 2) clamped into [min_time, max_time]: EVO1's training times, (0.02, 0.98) by default.

    Beta(2, 2) is the median of three independent uniforms (the second of three order statistics), so it is drawn
    from the caller's generator, reproducibly. It is symmetric about 1/2, so EVO1's times (t = 0 noise) read in this
    library's direction (t = 1 noise) are the same distribution.
    """

    min_time: float = 0.02
    max_time: float = 0.98

    def __post_init__(self) -> None:
        if not 0 <= self.min_time < self.max_time <= 1:
            raise InvalidInputError(f"need 0 <= min_time < max_time <= 1, got {self.min_time}, {self.max_time}")

    def __call__(
        self, batch_size: int, *, device: torch.device | str = "cpu", generator: torch.Generator | None = None
    ) -> Tensor:
        u = torch.rand(batch_size, 3, device=device, generator=generator)
        return u.median(dim=1).values.clamp(self.min_time, self.max_time)


@dataclass(frozen=True)
class ShiftedTimeSampler:
    """``base``'s times pushed toward the noisy end t = 1: t -> s t / (1 + (s - 1) t), with s = ``shift``.

    The time shift of SD3 (Esser et al., 2024), read in this library's convention (t = 1 is noise). arXiv 2606.05737
    ("Let It Be Simple") trains one-step VLAs on pi0's Beta(1.5, 1) shifted by s = 4, its best of 3, 4 and 8 at one
    step. The map is increasing and keeps t = 0 and t = 1 where they are, so times stay in (0, 1]; s > 1 moves
    every time toward noise (t = 0.5 becomes s / (s + 1): 0.8 at s = 4), s = 1 changes nothing.
    """

    base: TimeSampler
    shift: float

    def __post_init__(self) -> None:
        if not self.shift > 0:
            raise InvalidInputError(f"a time shift must be positive, got {self.shift}")

    def __call__(
        self, batch_size: int, *, device: torch.device | str = "cpu", generator: torch.Generator | None = None
    ) -> Tensor:
        time = self.base(batch_size, device=device, generator=generator)
        return self.shift * time / (1 + (self.shift - 1) * time)


def shifted(sampler: TimeSampler, shift: float) -> TimeSampler:
    """``sampler`` with its times shifted by ``shift`` (:class:`ShiftedTimeSampler`); ``sampler`` itself at 1, so
    its draws stay bit for bit what they were."""
    return sampler if shift == 1 else ShiftedTimeSampler(sampler, shift)


# each named distribution's sampler, from its number (:mod:`snapflow.flow.time_distribution` declares them; a test
# holds the two to the same names)
_SAMPLERS: dict[str, Callable[[Any], TimeSampler]] = {
    "uniform": lambda _: UniformTimeSampler(),
    "beta": lambda concentration: BetaTimeSampler(concentration),
    "shift": lambda shift: ShiftedTimeSampler(BetaTimeSampler(), shift),
}


def time_sampler_for(distribution: str) -> TimeSampler:
    """The sampler of a named time distribution (``uniform``, ``beta:1.5``, ``shift:4``: see
    :data:`snapflow.flow.time_distribution.TIME_DISTRIBUTIONS`); a mistake in its name an ``InvalidInputError``.

    Examples:
        >>> from snapflow.flow.time_sampling import time_sampler_for
        >>> time_sampler_for("uniform"), time_sampler_for("beta:1.5")
        (UniformTimeSampler(), BetaTimeSampler(concentration=1.5, min_time=0.001))
    """
    name, number = parse_time_distribution(distribution)
    return _SAMPLERS[name](number)


__all__ = [
    "TimeSampler",
    "UniformTimeSampler",
    "BetaTimeSampler",
    "Beta22TimeSampler",
    "ShiftedTimeSampler",
    "shifted",
    "time_sampler_for",
]
