"""Typed evaluation results; ``to_dict()`` gives the JSON of ``report.json``."""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from snapflow.benchmark.latency import LatencyRow
from snapflow.evaluation.switches import SwitchSmoothness
from snapflow.reporting.records import without_unset
from snapflow.reporting.statistics import paired_difference, wilson_interval


@dataclass(frozen=True)
class EpisodeResult:
    """One episode; ``path_mode``: which of the benchmark's path modes its path took (-1 none), where it has modes;
    ``switches``: how smoothly its chunks joined, where measured (under real-time chunking)."""

    task: str
    variation: int
    success: bool
    steps: int
    path_mode: int | None = None
    switches: SwitchSmoothness | None = None

    def to_dict(self) -> dict[str, Any]:
        """As an episode log holds it (the path mode as ``mode``): what was not measured left out, as in the logs
        written before either could be."""
        episode = {**asdict(self), "mode": self.path_mode, "switches": self.switches and self.switches.to_dict()}
        del episode["path_mode"]
        return without_unset(episode, ("mode", "switches"))

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> EpisodeResult:
        switches = SwitchSmoothness.from_dict(data["switches"]) if "switches" in data else None
        episode = {key: value for key, value in data.items() if key not in ("mode", "switches")}
        return cls(**episode, path_mode=data.get("mode"), switches=switches)


@dataclass(frozen=True)
class SuccessCount:
    successes: int
    episodes: int
    success_rate: float


def success_by_task(results: list[EpisodeResult]) -> dict[str, SuccessCount]:
    """Per task: successes, episodes and rate; plus ``mean``: all episodes, and the mean of the tasks' rates."""
    counts: dict[str, list[int]] = {}
    for result in results:
        entry = counts.setdefault(result.task, [0, 0])
        entry[0] += int(result.success)
        entry[1] += 1
    table = {
        task: SuccessCount(successes, episodes, successes / episodes) for task, (successes, episodes) in counts.items()
    }
    rates = [entry.success_rate for entry in table.values()]
    table["mean"] = SuccessCount(
        sum(e.successes for e in table.values()), sum(e.episodes for e in table.values()), float(np.mean(rates))
    )
    return table


@dataclass(frozen=True)
class OfflineMetrics:
    """Per-sample MSE of predicted chunks (normalised actions) summarised, and the mean cosine similarity."""

    samples: int
    mse: float
    mse_median: float
    mse_std: float
    mse_p90: float
    mse_p95: float
    cosine: float


@dataclass
class EvaluationRow:
    """One (policy, sampling mode): closed-loop success per task and, with held-out data, offline action error."""

    policy: str
    mode: str
    nfe: int
    success: dict[str, SuccessCount]
    closed_loop_s: float
    offline: OfflineMetrics | None = None
    path_modes: dict[str, list[int]] | None = None  # per task, episodes per path mode (path_modes_by_task)
    switches: SwitchSmoothness | None = None  # the episodes' chunk switches (under real-time chunking)

    def to_dict(self) -> dict[str, Any]:
        row = {**asdict(self), "switches": self.switches and self.switches.to_dict()}
        return without_unset(row, ("offline", "path_modes", "switches"))

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> EvaluationRow:
        return cls(
            data["policy"],
            data["mode"],
            data["nfe"],
            {task: SuccessCount(**entry) for task, entry in data["success"].items()},
            data["closed_loop_s"],
            OfflineMetrics(**data["offline"]) if "offline" in data else None,
            data.get("path_modes"),
            SwitchSmoothness.from_dict(data["switches"]) if "switches" in data else None,
        )


@dataclass
class EvaluationReport:
    """Rows by label on one benchmark's tasks; ``latency`` by label; ``timings`` and ``preset`` from the demo."""

    env: str
    tasks: list[str]
    episodes_per_task: int
    n_act: int
    rows: dict[str, EvaluationRow]
    latency: dict[str, LatencyRow] = field(default_factory=dict)
    timings: dict[str, float] = field(default_factory=dict)
    preset: dict[str, Any] = field(default_factory=dict)
    machine: str | None = None
    versions: dict[str, str] = field(default_factory=dict)  # what it ran under (reporting.machine.versions)
    first_variation: int = 0  # each task's episodes ran on its evaluation variations from this one on
    max_episode_steps: int | None = None  # each episode was cut here, short of the benchmark's own limit
    rtc: dict[str, Any] | None = None  # real-time chunking under an inference delay (RealTimeChunking.to_dict())

    def intervals(self) -> dict[str, dict[str, float]]:
        """Per row: mean success (%), its 95% Wilson interval over the pooled episodes and, for every row after the
        first, its difference from the first row in points, paired over tasks (both rows run the same evaluation
        variations of each task) with a 95% percentile-bootstrap interval."""
        labels = list(self.rows)
        reference = [self.rows[labels[0]].success[task].success_rate for task in self.tasks]
        result = {}
        for label, row in self.rows.items():
            mean = row.success["mean"]
            low, high = wilson_interval(mean.successes, mean.episodes)
            entry = {"success": 100 * mean.success_rate, "low": 100 * low, "high": 100 * high}
            if label != labels[0]:
                rates = [row.success[task].success_rate for task in self.tasks]
                difference, d_low, d_high = paired_difference(rates, reference)
                entry |= {
                    "difference": 100 * difference,
                    "difference_low": 100 * d_low,
                    "difference_high": 100 * d_high,
                }
            result[label] = entry
        return result

    def to_dict(self) -> dict[str, Any]:
        report: dict[str, Any] = {
            "env": self.env,
            "tasks": self.tasks,
            "episodes_per_task": self.episodes_per_task,
            "first_variation": self.first_variation,
            "n_act": self.n_act,
            **({"max_episode_steps": self.max_episode_steps} if self.max_episode_steps else {}),
            **({"rtc": self.rtc} if self.rtc else {}),
            "rows": {label: row.to_dict() for label, row in self.rows.items()},
            "intervals": self.intervals(),
        }
        if self.latency:
            report["latency"] = {label: row.to_dict() for label, row in self.latency.items()}
        if self.timings:
            report["timings"] = self.timings
        if self.preset:
            report["preset"] = self.preset
        if self.machine:
            report["machine"] = self.machine
        if self.versions:
            report["versions"] = self.versions
        return report


__all__ = [
    "EpisodeResult",
    "SuccessCount",
    "success_by_task",
    "OfflineMetrics",
    "EvaluationRow",
    "EvaluationReport",
]
