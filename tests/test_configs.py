"""Every committed sweep config loads, and every task it collects demonstrations of has a scripted expert, so a
sweep started from it does not stop at its first collection job hours later."""

from __future__ import annotations

from pathlib import Path

import pytest

from snapflow.envs.factory import make_benchmark
from snapflow.jobs.sweep.schema import load_sweep

CONFIGS = sorted((Path(__file__).resolve().parents[1] / "configs" / "sweeps").glob("*.toml"))


@pytest.mark.parametrize("path", CONFIGS, ids=[path.stem for path in CONFIGS])
def test_a_committed_sweep_config_loads_and_has_an_expert_for_every_task(path):
    config = load_sweep(path)
    benchmark = make_benchmark(config.data.env)
    assert config.data.tasks and config.tables
    for task in config.data.tasks:
        benchmark.make_expert(task)  # raises, naming the task, where no expert covers it


def test_the_four_suite_sweep_collects_all_of_liberos_forty_tasks_at_the_size_the_policy_reads():
    """LIBERO's four suites, every task with an expert since LIBERO-Goal task 3 and LIBERO-10 task 9 got theirs;
    frames at the 64 px read, kept as video; one SmolVLM size (a second would cost more than its three hours)."""
    from snapflow.envs.libero import Libero

    config = load_sweep(Path(__file__).resolve().parents[1] / "configs" / "sweeps" / "smolvla-libero-four-suites.toml")
    assert config.data.image_size == 64
    assert config.data.video is not None and config.data.video.codec == "libsvtav1"
    assert {run.spec.smolvlm for run in config.runs.values() if run.spec is not None} == {"small"}
    assert config.runs["lerobot-train"].trainer == "lerobot-train"
    suites = ("libero_spatial", "libero_object", "libero_goal", "libero_10")
    assert sorted(config.data.tasks) == sorted(task for suite in suites for task in Libero().task_sets[suite])
