"""A sweep's tables in Markdown: each table with its caption and footnotes, per task, the blocks a results document
holds between markers, and ``tables.md``."""

from __future__ import annotations

import os
import re
from pathlib import Path

import numpy as np

from snapflow.evaluation.path_modes import PATH_MODES_NOTE, markdown_path_modes
from snapflow.evaluation.switches import SWITCHES_NOTE, markdown_switches
from snapflow.jobs.sweep.aggregate import SetSummary, SweepRow, TableResult
from snapflow.jobs.sweep.specs import SweepConfig
from snapflow.reporting.tables import markdown_table


def _interval_cells(row: SweepRow) -> list[str]:
    interval = "{:.1f}-{:.1f}".format(*row.success_interval) if row.success_interval else "-"
    if row.difference is None:
        return [interval, "reference"]
    difference = row.difference
    return [interval, f"{difference.mean:+.1f} ({difference.low:+.1f}, {difference.high:+.1f})"]


def _variations(result: TableResult) -> str:
    """Which evaluation variations, where not the first ones, and where episodes were cut short (the tables' captions
    before either could be chosen say neither)."""
    first, cut = result.first_variation, result.max_episode_steps
    variations = f"; evaluation variations {first}-{first + result.episodes_per_task - 1} of each task" if first else ""
    return variations + (f"; every episode cut at {cut} steps" if cut is not None else "")


def markdown_rows(config: SweepConfig, result: TableResult, command: str) -> str:
    """The table with its caption (how it was made, wall times) and footnotes."""
    rows = result.rows
    episodes = rows[0].episodes // len(result.seeds)
    train_minutes = [np.mean(row.training_s) / 60 for row in rows]
    caption = (
        f"**{result.title}** ({config.title}). `{command}`; seeds {', '.join(map(str, result.seeds))}; "
        f"{result.episodes_per_task} episodes per task ({episodes} per seed and row{_variations(result)}); "
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
    if borrowed := [row for row in rows if row.sweep is not None]:
        lines += [
            "",
            "Read from another sweep's records (the same benchmark, tasks and evaluation variations): "
            + "; ".join(f"{row.label} (sweep {row.sweep}, run {row.run})" for row in borrowed)
            + ".",
        ]
    lines += [
        "",
        "s / training step: median over seeds of the run's own training wall time per step (the teacher's for "
        "teacher rows), each job on cores / workers threads.",
    ]
    return "\n".join(lines)


def markdown_per_task(result: TableResult) -> str:
    """Success % per task (mean over seeds), one column per row."""
    tasks = result.rows[0].per_task  # the table's own tasks, in the data's order
    cells = [[task, *(f"{row.per_task[task]:.1f}" for row in result.rows)] for task in tasks]
    return markdown_table(["task", *(row.label for row in result.rows)], cells)


def _summary_cell(summary: SetSummary) -> str:
    low, high = summary.success_interval
    cell = f"{summary.success_mean:.1f} ({low:.1f}-{high:.1f})"
    if summary.difference is not None:
        difference = summary.difference
        cell += f"; {difference.mean:+.1f} ({difference.low:+.1f}, {difference.high:+.1f})"
    return cell


def markdown_per_set(result: TableResult) -> str:
    """Each row on each named set of the tasks: success % (95% Wilson) and the paired difference to the reference
    row (95% bootstrap), then each contrast of two rows, overall and per set."""
    sets = result.rows[0].per_set or {}
    header = ["row", *(f"{name} ({summary.tasks} tasks)" for name, summary in sets.items())]
    cells = [[row.label, *(_summary_cell(summary) for summary in (row.per_set or {}).values())] for row in result.rows]
    lines = [markdown_table(header, cells)] if sets else []
    for contrast in result.contrasts or []:
        parts = [("overall", contrast.overall), *contrast.per_set.items()]
        described = "; ".join(
            f"{name} {difference.mean:+.1f} ({difference.low:+.1f}, {difference.high:+.1f}; {difference.cells} cells)"
            for name, difference in parts
        )
        lines.append(f"- {contrast.row} minus {contrast.overall.reference}, paired: {described}")
    return "\n\n".join(lines)


def replace_block(document: str, key: str, body: str) -> str:
    """Put ``body`` between the ``<!-- sweep:KEY -->`` and ``<!-- /sweep:KEY -->`` markers (appended if absent)."""
    start, end = f"<!-- sweep:{key} -->", f"<!-- /sweep:{key} -->"
    block = f"{start}\n{body}\n{end}"
    pattern = re.compile(re.escape(start) + r".*?" + re.escape(end), re.DOTALL)
    if pattern.search(document):
        return pattern.sub(lambda _: block, document)
    return document.rstrip("\n") + f"\n\n{block}\n"


def markdown_blocks(config: SweepConfig, results: dict[str, TableResult], directory: Path) -> dict[str, str]:
    """Each finished table's block (``sweep-name/table-name`` -> Markdown) for a file in ``directory``, which links its
    plot; tables not in ``results`` yet have none."""
    command = f"snapflow sweep {config.source.as_posix()}"
    link = Path(os.path.relpath(config.results_dir, directory)).as_posix()
    blocks = {}
    for table in (table for table in config.tables if table.name in results):
        key = f"{config.name}/{table.name}"
        body = markdown_rows(config, results[table.name], command)
        if table.per_task:
            body += "\n\nPer task, success % (mean over seeds):\n\n" + markdown_per_task(results[table.name])
        if table.per_set or table.contrasts:
            body += (
                "\n\nPer set of tasks, success % (95% Wilson interval); points from the reference row, paired over "
                "the set's (seed, task) cells (95% bootstrap interval):\n\n" + markdown_per_set(results[table.name])
            )
        if any(row.path_modes is not None for row in results[table.name].rows):
            modes = {row.label: row.path_modes for row in results[table.name].rows if row.path_modes}
            body += f"\n\nWhere the executed paths went (every seed's episodes). {PATH_MODES_NOTE}\n\n"
            body += markdown_path_modes(modes)
        if any(row.switches is not None for row in results[table.name].rows):
            body += f"\n\nHow smoothly the chunks joined (mean over seeds). {SWITCHES_NOTE}\n\n" + markdown_switches(
                {row.label: row.switches for row in results[table.name].rows if row.switches}
            )
        blocks[key] = f"{body}\n\n![{key}]({link}/{table.name}.png)"
    return blocks


def tables_markdown(config: SweepConfig, results: dict[str, TableResult]) -> str:
    """The sweep's ``tables.md``."""
    tables = "\n\n".join(
        f"### {key}\n\n{body}" for key, body in markdown_blocks(config, results, config.results_dir).items()
    )
    return f"# {config.title}\n\n{tables}\n"


__all__ = [
    "markdown_rows",
    "markdown_per_task",
    "markdown_per_set",
    "replace_block",
    "markdown_blocks",
    "tables_markdown",
]
