"""`snapflow toy-compare` on the shared job runner: the committed runs are recognised as done and reproduce their
comparison byte for byte (fast); a run made with other settings runs again, the others are reused (slow: it trains)."""

from __future__ import annotations

import json
import shutil
from dataclasses import replace
from pathlib import Path

import pytest

from snapflow.cli import main
from snapflow.jobs.runner import is_done
from snapflow.jobs.toy_compare import ToyJob, compare_targets
from snapflow.jobs.toy_config import RECORDED_SETTINGS, BiasedOneStep, RecipeOption, ToyConfig, toy_distill_settings
from snapflow.reporting.machine import versions
from snapflow.training.recipes import TargetOption

RESULTS = Path(__file__).resolve().parents[2] / "docs" / "results"
COMMITTED = sorted(path.name for path in RESULTS.glob("toy-targets*"))


def committed(name: str) -> tuple[list[TargetOption], list[int], ToyConfig]:
    """The options, seeds and base config of a committed comparison."""
    summary = json.loads((RESULTS / name / "comparison.json").read_text())
    steps = [
        row["target_steps"] if isinstance(row["target_steps"], int) else tuple(row["target_steps"])
        for row in summary["rows"]
    ]
    options = [TargetOption(row["target"], k) for row, k in zip(summary["rows"], steps, strict=True)]
    given = {key: value for key, value in summary["config"].items() if value is not None}
    settings = {name: given.pop(name) for name in RECORDED_SETTINGS if name in given}
    base = ToyConfig(**given, distill=toy_distill_settings(**settings))
    return options, summary["seeds"], base


@pytest.mark.parametrize("name", COMMITTED)
def test_the_committed_runs_are_done_for_their_settings_and_stale_for_others(name):
    options, seeds, base = committed(name)
    for option in options:
        for seed in seeds:
            config = replace(base, seed=seed, distill=option.settings(base.distill))
            path = RESULTS / name / "runs" / option.name / f"seed-{seed}.json"
            assert is_done(ToyJob(option.name, config, path))
            assert not is_done(ToyJob(option.name, replace(config, distill_steps=config.distill_steps + 1), path))


def test_a_finished_comparison_reruns_nothing_and_rewrites_its_table_byte_for_byte(tmp_path):
    name = "toy-targets"
    shutil.copytree(RESULTS / name / "runs", tmp_path / "runs")
    options, seeds, base = committed(name)
    compare_targets(options, seeds, base, tmp_path, workers=2, progress=False)  # training 18 runs would take minutes
    for file in ("comparison.md", "comparison.json"):
        assert (tmp_path / file).read_text() == (RESULTS / name / file).read_text()
    for run in (tmp_path / "runs").rglob("*.json"):
        assert run.read_text() == (RESULTS / name / run.relative_to(tmp_path)).read_text()


def test_a_target_option_without_steps_is_refused(tmp_path, capsys):
    with pytest.raises(SystemExit) as refusal:  # argparse's own refusal, before anything runs
        main(["toy-compare", "--targets", "euler", "--output", str(tmp_path), "--no-progress"])
    assert refusal.value.code == 2 and "TARGET:STEPS" in capsys.readouterr().err


@pytest.mark.slow
def test_toy_compare_writes_a_table_per_target_reuses_finished_runs_and_reruns_stale_ones(tmp_path):
    options = [TargetOption.parse(text) for text in ("euler:2", "euler:2,4", "bootstrap:4")]
    base = ToyConfig(
        teacher_steps=10, distill_steps=8, batch_size=32, hidden_dim=32, eval_contexts=3, samples_per_context=50
    )
    summary = compare_targets(options, [0, 1], base, tmp_path, workers=2, progress=False)
    assert [row["option"] for row in summary["rows"]] == ["euler-2", "euler-2-4", "bootstrap-4"]
    first, schedule, _ = summary["rows"]
    assert first["ratio_to_first_mean"] == 1.0 and len(first["distance_per_seed"]) == 2
    assert [row["teacher_passes_per_row"] for row in summary["rows"]] == [2.0, 3.0, 2.0]
    run = json.loads((tmp_path / "runs" / "euler-2-4" / "seed-1.json").read_text())
    assert list(run) == [
        *("config", "energy_distance", "distill_step_s", "coverage_error", "mode_shares", "true_mode_weights"),
        "versions",
    ]
    assert run["versions"] == versions(), "each run notes the versions it was made under"
    assert run["config"] == json.loads(
        json.dumps(replace(base, seed=1, distill=options[1].settings(base.distill)).record())
    )
    assert schedule["distance_per_seed"][1] == run["energy_distance"]["snapflow-1"]
    assert summary["teacher-10"]["per_seed"][1] == run["energy_distance"]["teacher-10"], (
        "one teacher per seed, whatever the target"
    )
    assert (tmp_path / "comparison.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "| bootstrapped (K -> 4) |" in (tmp_path / "comparison.md").read_text()

    runs = sorted((tmp_path / "runs").rglob("*.json"))
    stamps = {path: path.stat().st_mtime_ns for path in runs}
    assert compare_targets(options, [0, 1], base, tmp_path, progress=False) == summary
    assert stamps == {path: path.stat().st_mtime_ns for path in runs}, "finished runs are reused"

    stale = tmp_path / "runs" / "euler-2" / "seed-0.json"
    record = json.loads(stale.read_text())
    record["config"]["distill_steps"] = 9  # as if made with other settings
    stale.write_text(json.dumps(record))
    stamps[stale] = stale.stat().st_mtime_ns
    compare_targets(options, [0, 1], base, tmp_path, progress=False)
    assert [path for path in runs if path.stat().st_mtime_ns != stamps[path]] == [stale], "only the stale run ran again"
    assert json.loads(stale.read_text())["config"] == replace(base, seed=0).record()


@pytest.mark.slow
def test_recipes_and_the_biased_one_step_are_rows_with_coverage_intervals_and_timed_step_costs(tmp_path):
    """On the held-out rings: a target, the modes recipe and the biased one step, each row with its settings, its
    mode coverage, its ratio's interval over seeds and its step cost relative to the first row's; the coverage plot."""
    options = [TargetOption.parse("euler:2"), RecipeOption("modes"), RecipeOption("modes-lean"), BiasedOneStep()]
    base = ToyConfig(
        teacher_steps=10, distill_steps=8, batch_size=32, hidden_dim=32, eval_contexts=3, samples_per_context=50
    )
    summary = compare_targets(
        options, [0, 1], replace(base, shape="rings"), tmp_path, workers=2, progress=False, step_repeats=1
    )
    first, modes, lean, biased = summary["rows"]
    assert (modes["option"], modes["target"], modes["student_rows_per_row"], modes["alpha"]) == (
        "recipe-modes",
        "energy",
        3,
        0.5,
    )
    assert (modes["teacher_passes_per_row"], lean["teacher_passes_per_row"], lean["student_rows_per_row"]) == (2, 0, 4)
    assert (biased["alpha"], biased["teacher_passes_per_row"], biased["student_rows_per_row"]) == (1.0, 0.0, 1)
    assert first["step_cost_ratio"] == 1.0 and modes["step_cost_ratio"] > 0
    assert summary["step_cost"]["clock"] == "process CPU time"
    for row in summary["rows"]:
        low, high = row["ratio_to_teacher_interval"]
        assert low <= row["ratio_to_teacher_mean"] <= high and 0 <= row["coverage_error_mean"] <= 1
    run = json.loads((tmp_path / "runs" / "biased-one-step" / "seed-0.json").read_text())
    assert run["config"]["shape"] == "rings" and run["config"]["time_shift"] == 4.0
    assert len(run["mode_shares"]["snapflow-1"]) == 3 and len(run["mode_shares"]["snapflow-1"][0]) == 3
    table = (tmp_path / "comparison.md").read_text()
    assert table.startswith("Toy conditional two rings, seeds 0, 1") and "(1 rounds, process CPU time)" in table
    assert "| teacher 10-NFE |" in table and "| recipe modes | 0.5 / 0.3 |" in table
    assert (tmp_path / "coverage.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
