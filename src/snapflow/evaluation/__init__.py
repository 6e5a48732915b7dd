"""Evaluation metrics."""

from snapflow.evaluation.distances import energy_distance

__all__ = ["energy_distance"]
