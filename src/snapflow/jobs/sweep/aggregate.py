"""A finished sweep table's rows over seeds: typed results (``SweepRow``, ``TableResult``, as ``results.json`` holds
them) aggregated from the cached evaluations and training histories, with their statistics (intervals, paired
differences against the table's reference row)."""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from snapflow.evaluation.results import EvaluationRow
from snapflow.jobs.runner import is_recorded, read_record
from snapflow.jobs.sweep.planning import eval_job, train_job
from snapflow.jobs.sweep.specs import RowSpec, SweepConfig, TableSpec
from snapflow.reporting.machine import warn_simulator_differences
from snapflow.reporting.statistics import mean_std, paired_difference, wilson_interval
from snapflow.training.trainer import HISTORY


@dataclass(frozen=True)
class OfflineSummary:
    """Offline metrics of a row, each the mean over seeds; ``samples``: held-out chunks per seed."""

    mse: float
    mse_p90: float
    mse_p95: float
    cosine: float
    samples: int


@dataclass(frozen=True)
class Difference:
    """A row's success minus the table's reference row's, in points, paired over (seed, task) cells (the same
    evaluation variations): the mean and its 95% bootstrap interval."""

    reference: str
    mean: float
    low: float
    high: float
    cells: int


@dataclass(frozen=True)
class SweepRow:
    """One table row over its seeds: success (percent; mean, sample std, per seed; episode counts), per task, the
    offline metrics when every seed has them, and wall times (evaluation summed; training per seed)."""

    label: str
    run: str
    mode: str
    nfe: int
    n_act: int
    series: str | None
    x: float | None
    seeds: list[int]
    success_mean: float
    success_std: float
    success_per_seed: list[float]
    successes: int
    episodes: int
    per_task: dict[str, float]
    evaluation_s: float
    training_s: list[float]  # the run's and, for a student, its teacher's
    step_s: list[float]  # the run's own seconds per training step
    offline: OfflineSummary | None = None
    success_interval: tuple[float, float] | None = None  # 95% Wilson interval of the pooled episodes, percent
    difference: Difference | None = None  # against the table's reference row (None for the reference itself)
    sweep: str | None = None  # the sweep whose run the row evaluates, when not the table's own

    def to_dict(self) -> dict[str, Any]:
        """As results.json holds it (the interval a list; what a row lacks left out), so that
        ``from_dict(d).to_dict() == d``."""
        row = asdict(self)
        for optional in ("offline", "success_interval", "difference", "sweep"):
            if row[optional] is None:
                del row[optional]
        if "success_interval" in row:
            row["success_interval"] = list(row["success_interval"])
        return row

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> SweepRow:
        return cls(
            **{
                **data,
                "offline": OfflineSummary(**data["offline"]) if "offline" in data else None,
                "success_interval": tuple(data["success_interval"]) if "success_interval" in data else None,
                "difference": Difference(**data["difference"]) if "difference" in data else None,
            }
        )


@dataclass(frozen=True)
class TableResult:
    name: str
    title: str
    episodes_per_task: int
    seeds: list[int]
    x_label: str | None
    rows: list[SweepRow]
    first_variation: int = 0  # each task's episodes from this evaluation variation on

    def to_dict(self) -> dict[str, Any]:
        table = {**asdict(self), "rows": [row.to_dict() for row in self.rows]}
        if not self.first_variation:  # the tables written before it could be chosen: the first variations
            del table["first_variation"]
        return table

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> TableResult:
        return cls(**{**data, "rows": [SweepRow.from_dict(row) for row in data["rows"]]})


def _evaluation(config: SweepConfig, table: TableSpec, row: RowSpec, seed: int) -> EvaluationRow:
    """The cached evaluation of one cell; a FileNotFoundError if it is missing or was made with other settings."""
    job = eval_job(config, table, row, seed)
    if not is_recorded(job):
        owner = row.owner(config)
        raise FileNotFoundError(
            f"{config.name}: table {table.name!r} is incomplete ({job.path} is missing or was made with other settings); "
            f"run the sweep {owner.source} first"
        )
    recorded = read_record(job)
    warn_simulator_differences(recorded.get("versions"), f"{config.name}: {job.describe()}")
    return EvaluationRow.from_dict(recorded)


def _history(config: SweepConfig, run: str, seed: int) -> dict[str, Any]:
    """The run's training steps and wall time: from its record, or, for a run recorded before records held them,
    from the history in its folder."""
    record = read_record(train_job(config, run, seed))
    return record if "wall_time_s" in record else json.loads((config.run_dir(run, seed) / HISTORY).read_text())


def _training_seconds(config: SweepConfig, run: str, seed: int) -> float:
    """Wall time of the run, plus its teacher's for a student (what it took to get the policy)."""
    teacher = config.runs[run].teacher
    return _history(config, run, seed)["wall_time_s"] + (_training_seconds(config, teacher, seed) if teacher else 0.0)


def _step_seconds(config: SweepConfig, run: str, seed: int) -> float:
    """Seconds per training step of the run itself (a student's cost, without its teacher's)."""
    history = _history(config, run, seed)
    return history["wall_time_s"] / history["step"]


def _cells(tasks: tuple[str, ...], evals: list[EvaluationRow]) -> list[float]:
    """Success percent per (seed, task): the units a paired comparison matches across rows."""
    return [100 * e.success[task].success_rate for e in evals for task in tasks]


def table_results(config: SweepConfig, table: TableSpec) -> TableResult:
    """The table's rows from the cached evaluations; a FileNotFoundError names the first one not done."""
    rows = []
    reference, tasks = table.reference_row, config.tasks_of(table)
    reference_cells = _cells(tasks, [_evaluation(config, table, reference, seed) for seed in table.seeds])
    for row in table.rows:
        evals = [_evaluation(config, table, row, seed) for seed in table.seeds]
        successes = sum(e.success["mean"].successes for e in evals)
        episodes = sum(e.success["mean"].episodes for e in evals)
        low, high = wilson_interval(successes, episodes)
        difference = None
        if row is not reference:
            cells = _cells(tasks, evals)
            difference = Difference(reference.label, *paired_difference(cells, reference_cells), cells=len(cells))
        rates = [100 * e.success["mean"].success_rate for e in evals]
        mean, std = mean_std(rates)
        offline = None
        if all(e.offline is not None for e in evals):
            means = {
                key: float(np.mean([getattr(e.offline, key) for e in evals]))
                for key in ("mse", "mse_p90", "mse_p95", "cosine")
            }
            offline = OfflineSummary(**means, samples=evals[0].offline.samples)
        rows.append(
            SweepRow(
                label=row.label,
                run=row.run,
                mode=row.mode.name,
                nfe=row.mode.num_steps,
                n_act=row.n_act,
                series=row.series,
                x=row.x,
                seeds=list(table.seeds),
                success_mean=mean,
                success_std=std,
                success_per_seed=rates,
                successes=successes,
                episodes=episodes,
                per_task={task: float(np.mean([100 * e.success[task].success_rate for e in evals])) for task in tasks},
                evaluation_s=sum(e.closed_loop_s for e in evals),
                training_s=[_training_seconds(row.owner(config), row.run, seed) for seed in table.seeds],
                step_s=[_step_seconds(row.owner(config), row.run, seed) for seed in table.seeds],
                offline=offline,
                success_interval=(100 * low, 100 * high),
                difference=difference,
                sweep=None if row.sweep is None else row.sweep.name,
            )
        )
    return TableResult(
        table.name,
        table.title,
        table.episodes_per_task,
        list(table.seeds),
        table.x_label,
        rows,
        table.first_variation,
    )


__all__ = ["OfflineSummary", "Difference", "SweepRow", "TableResult", "table_results"]
