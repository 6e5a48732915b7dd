"""A table's rows on each named set of its tasks (LIBERO's suites) and the contrasts of two rows: the arithmetic by hand
on a small case, then on LIBERO-Object's committed records, read by a table of a sweep of its own."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from snapflow.evaluation.results import EvaluationRow, SuccessCount
from snapflow.jobs.sweep import load_sweep
from snapflow.jobs.sweep.aggregate import TableResult, _set_summaries
from snapflow.jobs.sweep.markdown import markdown_per_set
from snapflow.jobs.sweep.results import write_results

ROOT = Path(__file__).resolve().parents[2]


def _row(successes: dict[str, int], episodes: int = 2) -> EvaluationRow:
    counts = {task: SuccessCount(won, episodes, won / episodes) for task, won in successes.items()}
    return EvaluationRow("policy", "mode", 1, counts, closed_loop_s=1.0)


def test_a_rows_summary_on_each_set_is_its_cells_there_paired_with_the_references():
    sets = {"x": ("a", "b"), "y": ("c",)}
    evals = [_row({"a": 1, "b": 2, "c": 0}), _row({"a": 2, "b": 2, "c": 1})]  # two seeds, two episodes a task
    reference = [_row({"a": 0, "b": 1, "c": 0}), _row({"a": 1, "b": 2, "c": 2})]
    summaries = _set_summaries(sets, evals, ("teacher", reference))
    x, y = summaries["x"], summaries["y"]
    # x: cells 50, 100, 100, 100 against 0, 50, 50, 100: mean 87.5, paired difference 37.5 over 4 cells, 7 of 8 won
    assert (x.tasks, x.success_mean, x.successes, x.episodes) == (2, 87.5, 7, 8)
    assert (x.difference.reference, x.difference.mean, x.difference.cells) == ("teacher", 37.5, 4)
    assert x.difference.low <= 37.5 <= x.difference.high
    # y: cells 0, 50 against 0, 100: mean 25, difference -25 over 2 cells, 1 of 4 won
    assert (y.tasks, y.success_mean, y.successes, y.episodes, y.difference.mean) == (1, 25.0, 1, 4, -25.0)
    assert y.success_interval[0] < 25.0 < y.success_interval[1]
    assert _set_summaries(sets, evals, None)["x"].difference is None  # the reference row itself


def _reader(directory: Path, table: str) -> Path:
    """A sweep of LIBERO-Object whose one table reads the committed ``libero-object`` sweep's teacher rows."""
    other = (ROOT / "configs" / "sweeps" / "libero-object.toml").as_posix()
    rows = (
        f'{{ label = "teacher", sweep = "{other}", run = "teacher", mode = "teacher-10" }}, '
        f'{{ label = "naive", sweep = "{other}", run = "teacher", mode = "naive" }}'
    )
    path = directory / "reader.toml"
    path.write_text(
        f'name = "reader"\noutput_dir = "{(directory / "runs").as_posix()}"\n'
        f'results_dir = "{(directory / "results").as_posix()}"\n[data]\nenv = "libero"\ntasks = "libero_object"\n'
        f'[runs.teacher]\n[[tables]]\nname = "t"\nepisodes_per_task = 10\n{table}rows = [{rows}]\n'
    )
    return path


def test_a_table_per_suite_with_a_contrast_reads_the_same_cells_as_its_rows(tmp_path, monkeypatch):
    """On one suite the set is every task: its summary is the row's own, and the contrast of naive against the
    teacher is naive's difference to the reference; all of it round-trips through results.json and renders."""
    monkeypatch.chdir(ROOT)
    config = load_sweep(_reader(tmp_path, 'per_set = true\ncontrasts = [["naive", "teacher"]]\n'))
    written = write_results(config)["tables"]["t"]
    result = TableResult.from_dict(written)
    assert result.to_dict() == written
    teacher, naive = result.rows
    for row in (teacher, naive):
        (name, summary), *others = row.per_set.items()
        assert name == "libero_object" and not others and summary.tasks == 10
        assert (summary.successes, summary.episodes) == (row.successes, row.episodes)
        assert summary.success_mean == pytest.approx(row.success_mean)
    assert teacher.per_set["libero_object"].difference is None
    assert naive.per_set["libero_object"].difference == naive.difference
    (contrast,) = result.contrasts
    assert contrast.row == "naive" and contrast.overall == naive.difference
    assert contrast.per_set == {"libero_object": naive.difference}
    rendered = markdown_per_set(result)
    assert "| row | libero_object (10 tasks) |" in rendered
    assert f"- naive minus teacher, paired: overall {naive.difference.mean:+.1f}" in rendered
    assert "Per set of tasks" in (tmp_path / "results" / "tables.md").read_text()
    stored = json.loads((tmp_path / "results" / "results.json").read_text())["tables"]["t"]
    assert stored["contrasts"][0]["row"] == "naive" and "per_set" in stored["rows"][0]


def test_a_contrast_names_rows_of_its_table(tmp_path):
    with pytest.raises(
        ValueError, match=r"contrasts must be \[row, against\] pairs of its rows \['teacher', 'naive'\]"
    ):
        load_sweep(_reader(tmp_path, 'contrasts = [["naive", "student"]]\n'))
