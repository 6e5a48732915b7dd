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


def test_the_four_suite_sweep_collects_every_task_that_has_an_expert_at_the_size_the_policy_reads():
    """38 of LIBERO's 40 tasks: the two without an expert when it was written are named in its comment; frames at
    the 64 px read."""
    config = load_sweep(Path(__file__).resolve().parents[1] / "configs" / "sweeps" / "smolvla-libero-four-suites.toml")
    assert len(config.data.tasks) == 38 and config.data.image_size == 64
    assert {run.lerobot.smolvlm for run in config.runs.values()} == {"small", "medium"}
    missing = {"libero_goal_3", "libero_10_9"}
    assert missing.isdisjoint(config.data.tasks) and len(missing | set(config.data.tasks)) == 40
