"""A table's mode coverage on a benchmark whose experts do every task in several ways (MT10's via-point variant):
which way each row's executed paths went, pooled over seeds, and the coverage error, by hand on a small case."""

from __future__ import annotations

from pathlib import Path

import pytest

from snapflow.evaluation.path_modes import ModeCoverage, markdown_path_modes
from snapflow.evaluation.results import EvaluationRow, SuccessCount
from snapflow.jobs.sweep import load_sweep
from snapflow.jobs.sweep.aggregate import SweepRow, _mode_coverage

ROOT = Path(__file__).resolve().parents[2]


def _row(path_modes: dict[str, list[int]] | None) -> EvaluationRow:
    counts = {task: SuccessCount(1, 4, 0.25) for task in ("a", "b")}
    return EvaluationRow("policy", "naive-1", 1, counts, closed_loop_s=1.0, path_modes=path_modes)


def test_a_rows_mode_coverage_pools_its_seeds_per_task_and_scores_each_task_against_the_experts_shares():
    config = load_sweep(ROOT / "configs" / "sweeps" / "mt10-via-points.toml")
    # two seeds, four episodes a task: task a goes left 4, right 3, neither 1; task b left 8
    evals = [_row({"a": [2, 2, 0], "b": [4, 0, 0]}), _row({"a": [2, 1, 1], "b": [4, 0, 0]})]
    coverage = _mode_coverage(config, "row", ("a", "b"), evals)
    assert coverage.names == ["left via-point", "right via-point"]
    assert coverage.shares == pytest.approx([75.0, 18.75, 6.25]) and coverage.episodes == 16
    # task a: shares (1/2, 3/8, 1/8) against (1/2, 1/2, 0): TV 1/8; task b: (1, 0, 0): TV 1/2; mean 5/16
    assert coverage.coverage_error == pytest.approx(5 / 16)
    with pytest.warns(UserWarning, match="row 'row' has an evaluation that records no path modes"):
        assert _mode_coverage(config, "row", ("a", "b"), [evals[0], _row(None)]) is None, "a seed without: none"
    # a task one seed never ran, and one no seed ran, count in neither the shares nor the error
    sparse = _mode_coverage(
        config, "row", ("a", "b", "c"), [_row({"a": [2, 2, 0]}), _row({"a": [0, 0, 0], "b": [4, 0, 0]})]
    )
    assert sparse.shares == pytest.approx([75.0, 25.0, 0.0]) and sparse.coverage_error == pytest.approx((0 + 0.5) / 2)


def test_mode_coverage_round_trips_through_results_and_renders_a_column_per_mode():
    coverage = ModeCoverage(["left via-point", "right via-point"], [40.0, 35.0, 25.0], 0.25, 100)
    row = SweepRow(
        "naive 1-NFE",
        "teacher",
        "naive-1",
        1,
        4,
        None,
        None,
        [0],
        50.0,
        0.0,
        [50.0],
        50,
        100,
        {"a": 50.0},
        1.0,
        [1.0],
        [0.1],
        path_modes=coverage,
    )
    assert SweepRow.from_dict(row.to_dict()) == row
    plain = SweepRow(**{**row.__dict__, "path_modes": None})
    assert "path_modes" not in plain.to_dict(), "results.json of benchmarks without modes keeps its form"
    rendered = markdown_path_modes({row.label: coverage})
    assert "| row | left via-point % | right via-point % | neither % | coverage error | episodes |" in rendered
    assert "| naive 1-NFE | 40.0 | 35.0 | 25.0 | 0.250 | 100 |" in rendered
