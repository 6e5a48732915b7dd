"""Learning test: SnapFlow 1-NFE on a conditional mixture with a known answer, and the `snapflow toy` CLI."""

from __future__ import annotations

import json

import torch

from snapflow.cli import main
from snapflow.experiments.toy import ConditionalGaussianMixture, ToyConfig, run_toy_experiment


def test_mixture_samples_follow_the_context_dependent_weights():
    mixture = ConditionalGaussianMixture()
    context = mixture.sample_contexts(1, torch.Generator().manual_seed(0)).repeat(20_000, 1)
    samples = mixture.sample(context, torch.Generator().manual_seed(1))
    nearest_mode = torch.cdist(samples, mixture.means).argmin(dim=1)
    frequencies = torch.bincount(nearest_mode, minlength=len(mixture.means)).float() / len(samples)
    assert torch.allclose(frequencies, mixture.mode_weights(context[:1])[0], atol=0.015)


def test_snapflow_one_step_halves_the_naive_one_step_distance():
    """The issue's bar: SnapFlow 1-NFE <= 0.5 x naive 1-NFE, default config, fixed seed."""
    result = run_toy_experiment(ToyConfig(), progress=False)
    teacher, naive, snapflow = (result.distances[k] for k in ("teacher-10", "naive-1", "snapflow-1"))
    print(f"energy distance: teacher-10 {teacher:.4f}, naive-1 {naive:.4f}, snapflow-1 {snapflow:.4f}")
    assert snapflow <= 0.5 * naive
    assert teacher < snapflow, "ten teacher steps should still beat any one-step sampler here"


def test_cli_prints_the_table_and_writes_png_and_json(tmp_path, capsys):
    code = main(["toy", "--teacher-steps", "30", "--distill-steps", "30", "--no-progress", "--output-dir", str(tmp_path)])
    assert code == 0
    printed = capsys.readouterr().out
    for label in ("teacher 10-NFE", "naive 1-NFE", "SnapFlow 1-NFE"):
        assert label in printed
    assert (tmp_path / "toy_samples.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    results = json.loads((tmp_path / "toy_results.json").read_text())
    assert set(results["energy_distance"]) == {"teacher-10", "naive-1", "snapflow-1"}
    assert results["config"]["distill_steps"] == 30
    assert not list(tmp_path.glob(".*.tmp*")), "no temporary file may be left behind"


def test_toy_compare_writes_a_table_per_target_reuses_finished_runs_and_refuses_stale_ones(tmp_path, capsys):
    arguments = ["toy-compare", "--targets", "euler:2", "euler:2,4", "bootstrap:4", "--seeds", "0", "1", "--teacher-steps", "10",
                 "--distill-steps", "8", "--workers", "2", "--output-dir", str(tmp_path), "--no-progress"]
    assert main(arguments) == 0
    summary = json.loads((tmp_path / "comparison.json").read_text())
    assert [row["option"] for row in summary["rows"]] == ["euler-2", "euler-2-4", "bootstrap-4"]
    first, schedule, bootstrap = summary["rows"]
    assert first["ratio_to_first_mean"] == 1.0 and len(first["distance_per_seed"]) == 2
    assert [row["teacher_passes_per_row"] for row in summary["rows"]] == [2.0, 3.0, 2.0]
    run = json.loads((tmp_path / "runs" / "euler-2-4" / "seed-1.json").read_text())
    assert run["config"]["target_steps"] == [2, 4] and run["config"]["seed"] == 1
    assert schedule["distance_per_seed"][1] == run["energy_distance"]["snapflow-1"]
    assert summary["teacher-10"]["per_seed"][1] == run["energy_distance"]["teacher-10"], "one teacher per seed, whatever the target"
    assert (tmp_path / "comparison.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "| bootstrapped (K -> 4) |" in capsys.readouterr().out

    stamps = {path: path.stat().st_mtime_ns for path in (tmp_path / "runs").rglob("*.json")}
    assert main(arguments) == 0
    assert stamps == {path: path.stat().st_mtime_ns for path in (tmp_path / "runs").rglob("*.json")}, "finished runs are reused"
    changed = [*arguments[:arguments.index("--distill-steps") + 1], "9", *arguments[arguments.index("--distill-steps") + 2:]]
    assert main(changed) == 2
    assert "made with other settings" in capsys.readouterr().err
    assert main(["toy-compare", "--targets", "euler", "--output-dir", str(tmp_path / "x"), "--no-progress"]) == 2
    assert "TARGET:STEPS" in capsys.readouterr().err
