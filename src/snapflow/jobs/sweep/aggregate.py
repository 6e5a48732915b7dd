"""A finished sweep table's rows over seeds: typed results (``SweepRow``, ``TableResult``, as ``results.json`` holds
them) aggregated from the cached evaluations and training histories, with their statistics (intervals, paired
differences against the table's reference row)."""

from __future__ import annotations

import json
import warnings
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from snapflow.envs.factory import make_benchmark
from snapflow.evaluation.path_modes import ModeCoverage, mode_coverage
from snapflow.evaluation.results import EvaluationRow
from snapflow.evaluation.switches import SwitchSmoothness, mean_smoothness
from snapflow.jobs.runner import is_recorded, read_record
from snapflow.jobs.sweep.planning import eval_job, train_job
from snapflow.jobs.sweep.specs import RowSpec, SweepConfig, TableSpec
from snapflow.reporting.machine import warn_simulator_differences
from snapflow.reporting.records import without_unset
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
class SetSummary:
    """A row on one named set of the table's tasks (one of LIBERO's suites): its mean success over the set's
    (seed, task) cells, its pooled episodes with their 95% Wilson interval, and its difference to the reference row
    paired over the same cells (None for the reference itself)."""

    tasks: int
    success_mean: float
    successes: int
    episodes: int
    success_interval: tuple[float, float]
    difference: Difference | None = None

    def to_dict(self) -> dict[str, Any]:
        summary = {**asdict(self), "success_interval": list(self.success_interval)}
        if self.difference is None:
            del summary["difference"]
        return summary

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> SetSummary:
        difference = Difference(**data["difference"]) if "difference" in data else None
        return cls(**{**data, "success_interval": tuple(data["success_interval"]), "difference": difference})


@dataclass(frozen=True)
class Contrast:
    """One row's success minus another's (``against``), paired over their (seed, task) cells: over every task of the
    table, and on each named set of them."""

    row: str
    overall: Difference
    per_set: dict[str, Difference]

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> Contrast:
        per_set = {name: Difference(**difference) for name, difference in data["per_set"].items()}
        return cls(data["row"], Difference(**data["overall"]), per_set)


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
    per_set: dict[str, SetSummary] | None = None  # on each named set of the tasks, where the table asks for it
    path_modes: ModeCoverage | None = None  # where the benchmark's tasks have several modes
    switches: SwitchSmoothness | None = None  # under real-time chunking: its chunk switches, mean over seeds

    def to_dict(self) -> dict[str, Any]:
        """As results.json holds it (the interval a list; what a row lacks left out), so that
        ``from_dict(d).to_dict() == d``."""
        row = {**asdict(self), "switches": self.switches and self.switches.to_dict()}
        optional = ("offline", "success_interval", "difference", "sweep", "per_set", "path_modes", "switches")
        row = without_unset(row, optional)
        if "success_interval" in row:
            row["success_interval"] = list(row["success_interval"])
        if self.per_set is not None:
            row["per_set"] = {name: summary.to_dict() for name, summary in self.per_set.items()}
        return row

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> SweepRow:
        return cls(
            **{
                **data,
                "offline": OfflineSummary(**data["offline"]) if "offline" in data else None,
                "success_interval": tuple(data["success_interval"]) if "success_interval" in data else None,
                "difference": Difference(**data["difference"]) if "difference" in data else None,
                "per_set": (
                    {name: SetSummary.from_dict(summary) for name, summary in data["per_set"].items()}
                    if "per_set" in data
                    else None
                ),
                "path_modes": ModeCoverage(**data["path_modes"]) if "path_modes" in data else None,
                "switches": SwitchSmoothness.from_dict(data["switches"]) if "switches" in data else None,
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
    contrasts: list[Contrast] | None = None  # the pairs of rows the table compares beside its reference
    max_episode_steps: int | None = None  # every episode cut there (None: the benchmark's own limit)

    def to_dict(self) -> dict[str, Any]:
        table = {**asdict(self), "rows": [row.to_dict() for row in self.rows]}
        if not self.first_variation:  # the tables written before it could be chosen: the first variations
            del table["first_variation"]
        for optional in ("contrasts", "max_episode_steps"):  # written only where set, as before they existed
            if table[optional] is None:
                del table[optional]
        return table

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> TableResult:
        contrasts = [Contrast.from_dict(contrast) for contrast in data["contrasts"]] if "contrasts" in data else None
        rows = [SweepRow.from_dict(row) for row in data["rows"]]
        return cls(**{**data, "rows": rows, "contrasts": contrasts})


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


def _difference(
    against: str, evals: list[EvaluationRow], others: list[EvaluationRow], tasks: tuple[str, ...]
) -> Difference:
    """``evals``' success minus ``others``' (the row ``against``), paired over their (seed, task) cells on ``tasks``."""
    cells = _cells(tasks, evals)
    return Difference(against, *paired_difference(cells, _cells(tasks, others)), cells=len(cells))


def _task_sets(config: SweepConfig, tasks: tuple[str, ...]) -> dict[str, tuple[str, ...]]:
    """The benchmark's named sets of tasks (LIBERO's suites), each with those of ``tasks`` it holds, if any."""
    sets = make_benchmark(config.data.env).task_sets
    chosen = {name: tuple(task for task in tasks if task in members) for name, members in sets.items()}
    return {name: members for name, members in chosen.items() if members}


def _set_summaries(
    sets: dict[str, tuple[str, ...]], evals: list[EvaluationRow], reference: tuple[str, list[EvaluationRow]] | None
) -> dict[str, SetSummary]:
    """A row on each set of tasks; ``reference``: the reference row's label and evaluations (None: it is that row)."""
    summaries = {}
    for name, members in sets.items():
        counts = [e.success[task] for e in evals for task in members]
        successes, episodes = sum(count.successes for count in counts), sum(count.episodes for count in counts)
        low, high = wilson_interval(successes, episodes)
        difference = None if reference is None else _difference(reference[0], evals, reference[1], members)
        mean = float(np.mean(_cells(members, evals)))
        summaries[name] = SetSummary(len(members), mean, successes, episodes, (100 * low, 100 * high), difference)
    return summaries


def _mode_coverage(
    config: SweepConfig, label: str, tasks: tuple[str, ...], evals: list[EvaluationRow]
) -> ModeCoverage | None:
    """A row's path modes over its seeds, pooled task by task, where every evaluation recorded them."""
    benchmark = make_benchmark(config.data.env)
    if any(e.path_modes is None for e in evals):
        if benchmark.path_modes:  # a record made before path modes were counted: evaluate it again to see them
            warnings.warn(
                f"{config.name}: row {label!r} has an evaluation that records no path modes (made before they were "
                "counted): it shows none until evaluated again",
                stacklevel=2,
            )
        return None
    return mode_coverage([e.path_modes for e in evals], tasks, benchmark.path_modes, benchmark.path_mode_weights)


def table_results(config: SweepConfig, table: TableSpec) -> TableResult:
    """The table's rows from the cached evaluations; a FileNotFoundError names the first one not done."""
    rows = []
    reference, tasks = table.reference_row, config.tasks_of(table)
    evaluations = {row.label: [_evaluation(config, table, row, seed) for seed in table.seeds] for row in table.rows}
    reference_evals = evaluations[reference.label]
    sets = _task_sets(config, tasks) if table.per_set else None
    for row in table.rows:
        evals = evaluations[row.label]
        successes = sum(e.success["mean"].successes for e in evals)
        episodes = sum(e.success["mean"].episodes for e in evals)
        low, high = wilson_interval(successes, episodes)
        difference = None if row is reference else _difference(reference.label, evals, reference_evals, tasks)
        per_set = None
        if sets is not None:
            per_set = _set_summaries(sets, evals, None if row is reference else (reference.label, reference_evals))
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
                per_set=per_set,
                path_modes=_mode_coverage(config, row.label, tasks, evals),
                switches=(
                    mean_smoothness([e.switches for e in evals]) if all(e.switches is not None for e in evals) else None
                ),
            )
        )
    contrasts = [
        Contrast(
            label,
            _difference(against, evaluations[label], evaluations[against], tasks),
            {
                name: _difference(against, evaluations[label], evaluations[against], members)
                for name, members in (sets or {}).items()
            },
        )
        for label, against in table.contrasts
    ]
    return TableResult(
        table.name,
        table.title,
        table.episodes_per_task,
        list(table.seeds),
        table.x_label,
        rows,
        table.first_variation,
        contrasts or None,
        table.max_episode_steps,
    )


__all__ = [
    "OfflineSummary",
    "ModeCoverage",
    "Difference",
    "SetSummary",
    "Contrast",
    "SweepRow",
    "TableResult",
    "table_results",
]
