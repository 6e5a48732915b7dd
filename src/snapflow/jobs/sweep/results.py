"""A finished sweep's tables: typed rows from the cached evaluations, ``results.json``, one PNG per table, and
Markdown (``tables.md``, and blocks between markers in a results document such as ``docs/RESULTS.md``)."""

from __future__ import annotations

import json
import os
import re
import textwrap
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from snapflow.evaluation.results import EvaluationRow
from snapflow.jobs.runner import is_done, read_record
from snapflow.jobs.sweep.planning import eval_job
from snapflow.jobs.sweep.schema import RowSpec, SweepConfig, TableSpec
from snapflow.reporting.figures import pyplot, save_figure
from snapflow.reporting.files import write_json, write_text
from snapflow.reporting.statistics import mean_std, paired_difference, wilson_interval
from snapflow.reporting.tables import markdown_table
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

    def to_dict(self) -> dict[str, Any]:
        """As results.json holds it (the interval a list), so that ``from_dict(d).to_dict() == d``."""
        row = asdict(self)
        for optional in ("offline", "success_interval", "difference"):
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

    def to_dict(self) -> dict[str, Any]:
        return {**asdict(self), "rows": [row.to_dict() for row in self.rows]}

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> TableResult:
        return cls(**{**data, "rows": [SweepRow.from_dict(row) for row in data["rows"]]})


def _evaluation(config: SweepConfig, table: TableSpec, row: RowSpec, seed: int) -> EvaluationRow:
    """The cached evaluation of one cell; a FileNotFoundError if it is missing or was made with other settings."""
    job = eval_job(config, table, row, seed)
    if not is_done(job):
        raise FileNotFoundError(
            f"{config.name}: table {table.name!r} is incomplete ({job.path} is missing or was made with other settings); "
            "run the sweep first"
        )
    return EvaluationRow.from_dict(read_record(job))


def _history(config: SweepConfig, run: str, seed: int) -> dict[str, Any]:
    return json.loads((config.run_dir(run, seed) / HISTORY).read_text())


def _training_seconds(config: SweepConfig, run: str, seed: int) -> float:
    """Wall time of the run, plus its teacher's for a student (what it took to get the policy)."""
    teacher = config.runs[run].teacher
    return _history(config, run, seed)["wall_time_s"] + (_training_seconds(config, teacher, seed) if teacher else 0.0)


def _step_seconds(config: SweepConfig, run: str, seed: int) -> float:
    """Seconds per training step of the run itself (a student's cost, without its teacher's)."""
    history = _history(config, run, seed)
    return history["wall_time_s"] / history["step"]


def _cells(config: SweepConfig, evals: list[EvaluationRow]) -> list[float]:
    """Success percent per (seed, task): the units a paired comparison matches across rows."""
    return [100 * e.success[task].success_rate for e in evals for task in config.data.tasks]


def table_results(config: SweepConfig, table: TableSpec) -> TableResult:
    """The table's rows from the cached evaluations; a FileNotFoundError names the first one not done."""
    rows = []
    reference = table.reference_row
    reference_cells = _cells(config, [_evaluation(config, table, reference, seed) for seed in table.seeds])
    for row in table.rows:
        evals = [_evaluation(config, table, row, seed) for seed in table.seeds]
        successes = sum(e.success["mean"].successes for e in evals)
        episodes = sum(e.success["mean"].episodes for e in evals)
        low, high = wilson_interval(successes, episodes)
        difference = None
        if row is not reference:
            cells = _cells(config, evals)
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
                per_task={
                    task: float(np.mean([100 * e.success[task].success_rate for e in evals]))
                    for task in config.data.tasks
                },
                evaluation_s=sum(e.closed_loop_s for e in evals),
                training_s=[_training_seconds(config, row.run, seed) for seed in table.seeds],
                step_s=[_step_seconds(config, row.run, seed) for seed in table.seeds],
                offline=offline,
                success_interval=(100 * low, 100 * high),
                difference=difference,
            )
        )
    return TableResult(table.name, table.title, table.episodes_per_task, list(table.seeds), table.x_label, rows)


def _interval_cells(row: SweepRow) -> list[str]:
    interval = "{:.1f}-{:.1f}".format(*row.success_interval) if row.success_interval else "-"
    if row.difference is None:
        return [interval, "reference"]
    difference = row.difference
    return [interval, f"{difference.mean:+.1f} ({difference.low:+.1f}, {difference.high:+.1f})"]


def markdown_rows(config: SweepConfig, result: TableResult, command: str) -> str:
    """The table with its caption (how it was made, wall times) and footnotes."""
    rows = result.rows
    episodes = rows[0].episodes // len(result.seeds)
    train_minutes = [np.mean(row.training_s) / 60 for row in rows]
    caption = (
        f"**{result.title}** ({config.title}). `{command}`; seeds {', '.join(map(str, result.seeds))}; "
        f"{result.episodes_per_task} episodes per task ({episodes} per seed and row); "
        f"wall time: evaluation {sum(row.evaluation_s for row in rows) / 60:.1f} min for the table, training "
        f"{min(train_minutes):.1f}-{max(train_minutes):.1f} min per policy (teacher included)."
    )
    header = [
        "row",
        "NFE",
        "n_act",
        "success % (mean ± std)",
        "per seed",
        "successes / episodes",
        "offline MSE",
        "P95",
        "cosine",
        "s / training step",
    ]
    intervals = any(row.success_interval for row in rows)  # results made before intervals render as they were
    if intervals:
        header[6:6] = ["95% interval", "paired Δ (95% interval)"]
    cells = []
    for row in rows:
        offline = row.offline
        metrics = (
            [f"{offline.mse:.4f}", f"{offline.mse_p95:.4f}", f"{offline.cosine:.3f}"] if offline else ["-", "-", "-"]
        )
        cells.append(
            [
                row.label,
                row.nfe,
                row.n_act,
                f"{row.success_mean:.1f} ± {row.success_std:.1f}",
                " / ".join(f"{rate:.1f}" for rate in row.success_per_seed),
                f"{row.successes} / {row.episodes}",
                *(_interval_cells(row) if intervals else []),
                *metrics,
                f"{np.median(row.step_s):.3f}",
            ]
        )
    lines = [caption, "", markdown_table(header, cells)]
    if any(row.offline for row in rows):
        lines += [
            "",
            f"Offline metrics: mean over seeds of {rows[0].offline.samples} held-out demonstration chunks per seed "
            "(normalised actions), the same chunks and noise for every row.",
        ]
    if any(row.difference for row in rows):
        difference = next(row.difference for row in rows if row.difference)
        lines += [
            "",
            "95% interval: Wilson score interval of the pooled episodes. Paired Δ: success minus the reference row's "
            f"({difference.reference}) in points, averaged over the {difference.cells} (seed, task) cells both rows ran "
            "on the same variations, with a 95% bootstrap interval over those cells.",
        ]
    lines += [
        "",
        "s / training step: median over seeds of the run's own training wall time per step (the teacher's for "
        "teacher rows), each job on cores / workers threads.",
    ]
    return "\n".join(lines)


def markdown_per_task(config: SweepConfig, result: TableResult) -> str:
    """Success % per task (mean over seeds), one column per row."""
    cells = [[task, *(f"{row.per_task[task]:.1f}" for row in result.rows)] for task in config.data.tasks]
    return markdown_table(["task", *(row.label for row in result.rows)], cells)


def _error_bar(row: SweepRow) -> tuple[float, float]:
    """Below and above the mean: to the 95% Wilson interval's ends, or one std where a row predates intervals."""
    if row.success_interval is None:
        return row.success_std, row.success_std
    low, high = row.success_interval
    return max(row.success_mean - low, 0.0), max(high - row.success_mean, 0.0)


TITLE_WIDTH = 90  # characters of a plot's title per line: a longer title ran off the figure's right edge


def plot_table(result: TableResult, path: Path) -> None:
    """Success with its 95% interval: lines over ``x`` when the rows carry one, bars otherwise."""
    plt = pyplot()
    rows = result.rows
    figure, axis = plt.subplots(figsize=(6.4, 3.8))
    if all(row.x is not None for row in rows):
        for series in dict.fromkeys(row.series for row in rows):
            points = sorted((row.x, row.success_mean, *_error_bar(row)) for row in rows if row.series == series)
            xs, means, below, above = zip(*points, strict=True)
            axis.errorbar(xs, means, yerr=[below, above], marker="o", capsize=3, label=series or "")
        axis.set_xlabel(result.x_label or "x")
        if any(row.series for row in rows):
            axis.legend()
    else:
        positions = np.arange(len(rows))
        axis.bar(
            positions,
            [row.success_mean for row in rows],
            yerr=np.array([_error_bar(row) for row in rows]).T,
            capsize=4,
            color="#4c72b0",
        )
        axis.set_xticks(positions, [row.label for row in rows], rotation=20, ha="right")
    interval = all(row.success_interval for row in rows)
    axis.set_ylabel("MT10 success % (95% Wilson interval)" if interval else "MT10 success % (mean ± std over seeds)")
    title = f"{result.title} ({len(result.seeds)} seed(s), {result.episodes_per_task} episodes per task)"
    axis.set_title(textwrap.fill(title, TITLE_WIDTH), fontsize=9)
    axis.grid(alpha=0.3)
    figure.tight_layout()
    save_figure(figure, path, dpi=120)


def replace_block(document: str, key: str, body: str) -> str:
    """Put ``body`` between the ``<!-- sweep:KEY -->`` and ``<!-- /sweep:KEY -->`` markers (appended if absent)."""
    start, end = f"<!-- sweep:{key} -->", f"<!-- /sweep:{key} -->"
    block = f"{start}\n{body}\n{end}"
    pattern = re.compile(re.escape(start) + r".*?" + re.escape(end), re.DOTALL)
    if pattern.search(document):
        return pattern.sub(lambda _: block, document)
    return document.rstrip("\n") + f"\n\n{block}\n"


def markdown_blocks(config: SweepConfig, results: dict[str, TableResult], directory: Path) -> dict[str, str]:
    """Each table's block (``sweep-name/table-name`` -> Markdown) for a file in ``directory``, which links its plot."""
    command = f"snapflow sweep {config.source.as_posix()}"
    link = Path(os.path.relpath(config.results_dir, directory)).as_posix()
    blocks = {}
    for table in config.tables:
        key = f"{config.name}/{table.name}"
        body = markdown_rows(config, results[table.name], command)
        if table.per_task:
            body += "\n\nPer task, success % (mean over seeds):\n\n" + markdown_per_task(config, results[table.name])
        blocks[key] = f"{body}\n\n![{key}]({link}/{table.name}.png)"
    return blocks


def tables_markdown(config: SweepConfig, results: dict[str, TableResult]) -> str:
    """The sweep's ``tables.md``."""
    tables = "\n\n".join(
        f"### {key}\n\n{body}" for key, body in markdown_blocks(config, results, config.results_dir).items()
    )
    return f"# {config.title}\n\n{tables}\n"


def write_results(
    config: SweepConfig, document: str | Path | None = None, tables: list[str] | None = None
) -> dict[str, Any]:
    """``results.json``, ``tables.md`` and one PNG per table in the sweep's results_dir; the tables also go
    into ``document`` (between their markers) if given. Returns the content of ``results.json``.

    ``tables``: rebuild only these from their evaluations; every other table is read back from the results.json
    already there and kept as it is (a FileNotFoundError names one it lacks). Raises FileNotFoundError naming the
    first evaluation not done when a rebuilt table has not run to the end.
    """
    rebuilt = config.table_names(tables)
    stored = config.results_dir / "results.json"
    earlier = json.loads(stored.read_text())["tables"] if stored.is_file() and len(rebuilt) < len(config.tables) else {}
    for table in config.tables:
        if table.name not in rebuilt and table.name not in earlier:
            raise FileNotFoundError(f"{stored} holds no table {table.name!r} to keep: run it too, or the whole sweep")
    results = {
        table.name: table_results(config, table)
        if table.name in rebuilt
        else TableResult.from_dict(earlier[table.name])
        for table in config.tables
    }
    for name in rebuilt:
        plot_table(results[name], config.results_dir / f"{name}.png")
    summary = {
        "sweep": config.name,
        "title": config.title,
        "config": config.source.as_posix(),
        "data": asdict(config.data),
        "tables": {name: result.to_dict() for name, result in results.items()},
    }
    write_json(config.results_dir / "results.json", summary)
    write_text(config.results_dir / "tables.md", tables_markdown(config, results))
    if document is not None:
        document = Path(document)
        text = document.read_text() if document.is_file() else "# Results\n"
        for key, body in markdown_blocks(config, results, document.parent).items():
            text = replace_block(text, key, body)
        write_text(document, text)
    return summary


__all__ = [
    "OfflineSummary",
    "SweepRow",
    "TableResult",
    "table_results",
    "markdown_rows",
    "markdown_per_task",
    "plot_table",
    "replace_block",
    "markdown_blocks",
    "tables_markdown",
    "write_results",
]
