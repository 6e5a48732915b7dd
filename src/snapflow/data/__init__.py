"""Demonstration storage and collection."""

from snapflow.data.demonstrations import Demonstrations, DemonstrationError, Episode, NormalizationStats

__all__ = ["Demonstrations", "DemonstrationError", "Episode", "NormalizationStats"]
