"""Learning test: SnapFlow 1-NFE on a conditional mixture with a known answer, and the `snapflow toy` CLI (the
comparison of targets, `snapflow toy-compare`, is tested in test_toy_compare.py)."""

from __future__ import annotations

import json
import math

import pytest
import torch

from snapflow.cli import main
from snapflow.data.toy_mixture import ConditionalGaussianMixture
from snapflow.jobs.toy import run_toy_experiment
from snapflow.jobs.toy_config import ToyConfig, toy_distill_settings
from tests.evaluation.figures import CYCLE, assert_figure, tint_share


def test_the_toys_record_holds_its_five_settings_in_place_and_another_only_off_the_toys_default():
    """The toy's cache key stays what its committed runs recorded (their settings flat among its own, in order);
    another distillation setting joins it where a run sets it."""
    record = ToyConfig().record()
    assert list(record) == [
        *("seed", "num_modes", "mode_radius", "teacher_steps", "distill_steps", "batch_size", "teacher_lr"),
        *("distill_lr", "alpha", "consistency_weight", "method", "target", "target_steps", "hidden_dim"),
        *("eval_contexts", "samples_per_context"),
    ]
    assert (record["alpha"], record["consistency_weight"], record["target_steps"]) == (0.5, 3.0, 2)
    frozen = ToyConfig(distill=toy_distill_settings(freeze_prefix=True, time_shift=2.0)).record()
    assert frozen == {**record, "freeze_prefix": True, "time_shift": 2.0}


def test_mixture_samples_follow_the_context_dependent_weights():
    mixture = ConditionalGaussianMixture()
    context = mixture.sample_contexts(1, torch.Generator().manual_seed(0)).repeat(20_000, 1)
    samples = mixture.sample(context, torch.Generator().manual_seed(1))
    nearest_mode = torch.cdist(samples, mixture.means).argmin(dim=1)
    frequencies = torch.bincount(nearest_mode, minlength=len(mixture.means)).float() / len(samples)
    assert torch.allclose(frequencies, mixture.mode_weights(context[:1])[0], atol=0.015)
    # every sample sits within a few standard deviations of its mode, the modes on a circle of the given radius
    assert (torch.cdist(samples, mixture.means).min(dim=1).values < 5 * mixture.mode_std).all()
    assert torch.allclose(mixture.means.norm(dim=1), torch.full((6,), 2.0))


@pytest.mark.slow
def test_snapflow_one_step_halves_the_naive_one_step_distance():
    """The issue's bar: SnapFlow 1-NFE <= 0.5 x naive 1-NFE, default config, fixed seed."""
    result = run_toy_experiment(ToyConfig(), progress=False)
    teacher, naive, snapflow = (result.distances[k] for k in ("teacher-10", "naive-1", "snapflow-1"))
    print(f"energy distance: teacher-10 {teacher:.4f}, naive-1 {naive:.4f}, snapflow-1 {snapflow:.4f}")
    assert snapflow <= 0.5 * naive
    assert teacher < snapflow, "ten teacher steps should still beat any one-step sampler here"


@pytest.mark.slow
def test_cli_prints_the_table_and_writes_png_and_json(tmp_path, capsys):
    code = main(["toy", "--teacher-steps", "30", "--distill-steps", "30", "--no-progress", "--output", str(tmp_path)])
    assert code == 0
    printed = capsys.readouterr().out
    results = json.loads((tmp_path / "toy_results.json").read_text())
    distances = results["energy_distance"]
    assert set(distances) == {"teacher-10", "naive-1", "snapflow-1"}
    assert all(math.isfinite(value) and value > 0 for value in distances.values())
    assert results["config"]["distill_steps"] == 30 and results["config"]["teacher_steps"] == 30
    assert results["config"] == {**ToyConfig().record(), "teacher_steps": 30, "distill_steps": 30}
    assert results["distill_step_s"] > 0 and results["wall_time_s"] > 0
    # the printed table shows the numbers of the JSON
    for label, key, nfe in (
        ("teacher 10-NFE", "teacher-10", 10),
        ("naive 1-NFE", "naive-1", 1),
        ("SnapFlow 1-NFE", "snapflow-1", 1),
    ):
        ratio = distances[key] / distances["naive-1"]
        assert f"| {label} | {nfe} | {distances[key]:.4f} | {ratio:.3f} |" in printed
    # a row per context (three), a column per sampler: the exact data in black, then each mode in its own colour
    # (C1, C2, C3, drawn at alpha 0.5); each mode's column shows its colour and no other's
    pixels = assert_figure(tmp_path / "toy_samples.png", (3.2 * 4, 3.2 * 3))
    width = pixels.shape[1] // 4
    for column in range(4):
        region = pixels[:, column * width : (column + 1) * width]
        for mode, colour in enumerate(CYCLE[1:4], start=1):
            share = tint_share(region, colour)
            assert (share > 0.002) if mode == column else (share == 0), (column, colour, share)
    assert not list(tmp_path.glob(".*.tmp*")), "no temporary file may be left behind"
