"""The scripted experts' success per task (``snapflow experts``), on the real simulator."""

from __future__ import annotations

import json

import pytest

from snapflow.cli import main
from snapflow.envs.metaworld import MetaWorld
from snapflow.evaluation.experts import EXPERTS_JSON, EXPERTS_MD
from snapflow.reporting.statistics import wilson_interval


@pytest.mark.slow
def test_experts_command_writes_each_tasks_success_with_its_interval(tmp_path, capsys):
    """Two tasks (one of MT10, one beyond it), 2 evaluation variations each, each task in a worker process of its
    own: the counts add up, every episode ran to success or the step limit, the report's mean is the mean of the
    tasks' rates, and each task's time per episode and the workers' peak memory are recorded."""
    output = tmp_path / "experts"
    arguments = ["experts", "--tasks", "reach-v3,handle-press-v3", "--episodes", "2", "--no-progress", "--workers", "2"]
    assert main([*arguments, "--output", str(output)]) == 0
    report = json.loads((output / EXPERTS_JSON).read_text())
    assert (report["env"], report["split"], report["episodes_per_task"]) == ("metaworld", "eval", 2)
    tasks = report["tasks"]
    assert list(tasks) == ["reach-v3", "handle-press-v3", "mean"]
    for task in ("reach-v3", "handle-press-v3"):
        entry = tasks[task]
        assert entry["episodes"] == 2 and entry["success_rate"] == entry["successes"] / 2
        assert entry["interval"] == list(wilson_interval(entry["successes"], 2))
        assert 1 <= entry["mean_steps"] <= MetaWorld.max_episode_steps
        assert entry["seconds_per_episode"] > 0
    assert tasks["mean"]["episodes"] == 4 and report["workers"] == 2 and report["peak_rss_mb"] > 50
    assert tasks["mean"]["success_rate"] == pytest.approx(
        (tasks["reach-v3"]["success_rate"] + tasks["handle-press-v3"]["success_rate"]) / 2
    )
    table = (output / EXPERTS_MD).read_text()
    assert f"| handle-press-v3 | {tasks['handle-press-v3']['successes']} / 2 |" in table
    assert "mean success over 2 task(s)" in capsys.readouterr().out


@pytest.mark.slow  # builds MT10 to count its variations
def test_experts_refuses_unknown_tasks_and_too_many_episodes_in_one_line(tmp_path, capsys):
    assert main(["experts", "--tasks", "reach-v3,teleport-v3", "--output", str(tmp_path / "a"), "--no-progress"]) == 2
    assert "unknown metaworld task(s) ['teleport-v3']" in capsys.readouterr().err
    assert main(["experts", "--tasks", "all", "--output", str(tmp_path / "b"), "--no-progress"]) == 2
    assert "give a set (mt10, mt50)" in capsys.readouterr().err
    assert main(["experts", "--tasks", "reach-v3", "--episodes", "51", "--output", str(tmp_path / "c")]) == 2
    assert (
        "episodes per task must be in [1, 50] (metaworld's 50 evaluation variations), got 51" in capsys.readouterr().err
    )
    assert not any((tmp_path / name).exists() for name in "abc")


def test_a_named_set_that_ran_whole_gets_its_mean_and_lowest_task():
    """MT10 ran whole: its mean is the mean of its tasks' rates; MT50 did not, so it has none."""
    from snapflow.envs.metaworld import MT10_TASKS
    from snapflow.evaluation.experts import set_means

    tasks = {
        task: {"success_rate": rate, "successes": round(50 * rate), "episodes": 50}
        for task, rate in zip(MT10_TASKS, [1.0, 0.9, 0.8, 1.0, 1.0, 1.0, 0.5, 1.0, 1.0, 1.0], strict=True)
    }
    assert set_means(MetaWorld(), tasks) == {
        "mt10": {"success_rate": pytest.approx(0.92), "successes": 460, "episodes": 500, "lowest_task_rate": 0.5}
    }
