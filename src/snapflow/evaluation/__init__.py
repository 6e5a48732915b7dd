"""Evaluation: closed-loop success on a benchmark, offline action error, sample distances, and their reports."""
