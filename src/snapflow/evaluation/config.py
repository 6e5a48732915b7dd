"""Evaluation defaults: plain Python, read by the CLI before torch loads."""

N_ACT = 4  # actions executed per predicted chunk before re-planning
OFFLINE_SAMPLES = 500  # held-out chunks scored offline, as the paper's Table 2

__all__ = ["N_ACT", "OFFLINE_SAMPLES"]
