"""A sweep table's figure: success with its 95% interval per row."""

from __future__ import annotations

import textwrap
from pathlib import Path

import numpy as np

from snapflow.jobs.sweep.aggregate import SweepRow, TableResult
from snapflow.reporting.figures import pyplot, save_figure


def _error_bar(row: SweepRow) -> tuple[float, float]:
    """Below and above the mean: to the 95% Wilson interval's ends, or one std where a row predates intervals."""
    if row.success_interval is None:
        return row.success_std, row.success_std
    low, high = row.success_interval
    return max(row.success_mean - low, 0.0), max(high - row.success_mean, 0.0)


TITLE_WIDTH = 90  # characters of a plot's title per line: a longer title ran off the figure's right edge


def plot_table(result: TableResult, path: Path, sweep_title: str) -> None:
    """Success with its 95% interval: lines over ``x`` when the rows carry one, bars otherwise; titled by the sweep
    (which names the benchmark) and the table."""
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
    axis.set_ylabel("success % (95% Wilson interval)" if interval else "success % (mean ± std over seeds)")
    title = f"{result.title} ({len(result.seeds)} seed(s), {result.episodes_per_task} episodes per task)"
    axis.set_title("\n".join(textwrap.fill(line, TITLE_WIDTH) for line in (sweep_title, title)), fontsize=9)
    axis.grid(alpha=0.3)
    figure.tight_layout()
    save_figure(figure, path, dpi=120)


__all__ = ["plot_table"]
