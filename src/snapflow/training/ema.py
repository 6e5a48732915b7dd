"""An exponential moving average of the trained weights, the copy a checkpoint saves for evaluation.

After optimiser step ``k`` (counted from 0) the average moves towards the weights by ``1 - d_k`` with
``d_k = min(decay, (1 + k) / (10 + k))``: the warm-up keeps the first steps from being dominated by the starting
weights (for a student, the teacher's), and later the average spans about ``1 / (1 - decay)`` steps.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

import torch
from torch import Tensor, nn

from snapflow.errors import InvalidInputError


class WeightAverage:
    """The average of ``parameters`` (by name), updated after each optimiser step."""

    def __init__(self, parameters: dict[str, nn.Parameter], decay: float) -> None:
        if not 0 < decay < 1:
            raise InvalidInputError(f"the average's decay must be between 0 and 1 (exclusive), got {decay}")
        self.parameters = parameters
        self.decay = decay
        self.average = {name: parameter.detach().clone() for name, parameter in parameters.items()}

    def decay_at(self, step: int) -> float:
        """The share of the old average kept after optimiser step ``step`` (0-based)."""
        return min(self.decay, (1 + step) / (10 + step))

    @torch.no_grad()
    def update(self, step: int) -> None:
        """Move the average towards the weights as they are after optimiser step ``step``."""
        weight = 1 - self.decay_at(step)
        for name, parameter in self.parameters.items():
            self.average[name].lerp_(parameter.detach(), weight)

    @contextmanager
    def applied(self) -> Iterator[dict[str, Tensor]]:
        """The average in the parameters for the ``with`` block (to save or evaluate it); yields a copy of the raw
        weights, which are put back afterwards."""
        raw = {name: parameter.detach().clone() for name, parameter in self.parameters.items()}
        try:
            self._load(self.average)
            yield raw
        finally:
            self._load(raw)

    @torch.no_grad()
    def _load(self, values: dict[str, Tensor]) -> None:
        for name, parameter in self.parameters.items():
            parameter.copy_(values[name])


__all__ = ["WeightAverage"]
