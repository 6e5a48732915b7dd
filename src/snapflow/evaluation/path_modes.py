"""Which way the executed paths went, on a benchmark whose experts do every task in several ways
(:attr:`~snapflow.envs.base.Benchmark.path_modes`, as MT10's via-point variant): each episode's mode as its
environment tells it, counted per task, and a row's shares and coverage error against the experts' own shares."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import torch

from snapflow.evaluation.distances import coverage_error
from snapflow.reporting.tables import markdown_table

if TYPE_CHECKING:
    from snapflow.evaluation.results import EpisodeResult

#: what the tables of path modes say beneath them
PATH_MODES_NOTE = (
    "Each episode's mode as its environment tells it (the via-point variant: the via-point the hand passed first), "
    "neither where it took none; coverage error: the mean over tasks of the total variation distance between a task's "
    "shares and the experts' draw (the via-point variant: each way with probability 0.5, none in neither)."
)


def path_modes_by_task(results: list[EpisodeResult], num_modes: int) -> dict[str, list[int]] | None:
    """Per task, how many episodes took each of ``num_modes`` path modes, the last column none of them; ``None``
    where the episodes record no mode (a benchmark without modes)."""
    if not num_modes or any(result.path_mode is None for result in results):
        return None
    counts: dict[str, list[int]] = {}
    for result in results:
        mode = result.path_mode if result.path_mode >= 0 else num_modes
        counts.setdefault(result.task, [0] * (num_modes + 1))[mode] += 1
    return counts


@dataclass(frozen=True)
class ModeCoverage:
    """A row's executed paths: ``shares``, percent of all its episodes per mode of ``names``, the last none of them;
    ``coverage_error``, the mean over tasks of the total variation distance between a task's shares and the experts'
    mode weights, none weighted 0 (0: every mode taken as often as the experts take it)."""

    names: list[str]
    shares: list[float]
    coverage_error: float
    episodes: int


def mode_coverage(
    counts: Sequence[dict[str, list[int]]], tasks: Sequence[str], names: Sequence[str], weights: Sequence[float]
) -> ModeCoverage:
    """The coverage of ``counts`` (per task, episodes per mode, as :func:`path_modes_by_task`; several of them, say a
    row's seeds, pooled task by task) against the experts' ``weights`` of the modes ``names``. A task with no
    episode in any of them counts in neither the shares nor the error."""
    none = [0] * (len(names) + 1)
    per_task = np.array([np.sum([count.get(task, none) for count in counts], axis=0) for task in tasks], dtype=float)
    per_task = per_task[per_task.sum(axis=1) > 0]
    if not len(per_task):
        raise ValueError("no episode to count the path modes of")
    shares = torch.from_numpy(per_task / per_task.sum(axis=1, keepdims=True))
    truth = torch.tensor(weights, dtype=torch.float64).expand(len(per_task), -1)
    pooled = per_task.sum(axis=0)
    return ModeCoverage(
        list(names),
        [float(x) for x in 100 * pooled / pooled.sum()],
        float(coverage_error(shares, truth)),
        int(pooled.sum()),
    )


def markdown_path_modes(rows: dict[str, ModeCoverage]) -> str:
    """Each labelled row's executed paths per mode (percent of its episodes) and its coverage error."""
    names = next(iter(rows.values())).names
    header = ["row", *(f"{name} %" for name in names), "neither %", "coverage error", "episodes"]
    cells = [
        [label, *(f"{share:.1f}" for share in row.shares), f"{row.coverage_error:.3f}", row.episodes]
        for label, row in rows.items()
    ]
    return markdown_table(header, cells)


__all__ = ["PATH_MODES_NOTE", "ModeCoverage", "markdown_path_modes", "mode_coverage", "path_modes_by_task"]
