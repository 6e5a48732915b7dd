"""Normalisation statistics of a demonstration set: numpy only, so data handling loads no torch."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class NormalizationStats:
    """Per-dimension mean and std; std is floored so constant dimensions (unused object slots) stay finite."""

    state_mean: list[float]
    state_std: list[float]
    action_mean: list[float]
    action_std: list[float]

    @classmethod
    def from_arrays(cls, states: np.ndarray, actions: np.ndarray, min_std: float = 1e-2) -> NormalizationStats:
        return cls(
            states.mean(0).tolist(),
            np.maximum(states.std(0), min_std).tolist(),
            actions.mean(0).tolist(),
            np.maximum(actions.std(0), min_std).tolist(),
        )


__all__ = ["NormalizationStats"]
