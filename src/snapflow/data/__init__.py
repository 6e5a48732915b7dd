"""Demonstrations: collection from a benchmark's experts, storage, and (observation, action chunk) training pairs."""

from snapflow.data.demonstrations import DemonstrationError, Demonstrations, Episode

__all__ = ["Demonstrations", "DemonstrationError", "Episode"]
