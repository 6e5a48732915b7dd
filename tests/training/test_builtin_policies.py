"""Every built-in policy goes through the same commands: ``snapflow collect`` once, then per policy ``train --policy-type``,
``distill``, ``eval --data`` and ``bench --policy``, each checked by what it wrote (simulator and end to end: slow)."""

from __future__ import annotations

import json

import pytest

from snapflow.cli import main
from snapflow.data.demonstrations import Demonstrations
from snapflow.policies.checkpoint import load_policy
from snapflow.policies.factory import POLICIES
from snapflow.reporting.files import recorded_path

TASKS = ("drawer-close-v3", "reach-v3")
EVAL_TASK = "drawer-close-v3"


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    directory = tmp_path_factory.mktemp("cli") / "data"
    assert (
        main(
            [
                "collect",
                "--env",
                "metaworld",
                "--tasks",
                ",".join(TASKS),
                "--episodes",
                "3",
                "--output",
                str(directory),
                "--no-progress",
            ]
        )
        == 0
    )
    return directory


@pytest.mark.slow
@pytest.mark.parametrize("policy", sorted(POLICIES))
def test_a_built_in_policy_trains_saves_loads_and_evaluates_through_the_same_commands(policy, data, tmp_path, capsys):
    demonstrations = Demonstrations.load(data)
    assert (
        demonstrations.tasks == list(TASKS) and len(demonstrations.episodes) == 6 and demonstrations.env == "metaworld"
    )
    teacher, student = tmp_path / "teacher", tmp_path / "student"
    flags = f"--policy-type {policy} --steps 4 --batch-size 8 --chunk-length 4 --no-progress".split()
    assert main(["train", "--data", str(data), "--output", str(teacher), *flags]) == 0
    flags = "--steps 2 --batch-size 8 --no-progress".split()
    assert main(["distill", "--teacher", str(teacher), "--data", str(data), "--output", str(student), *flags]) == 0

    assert demonstrations.split(0.1) == ([0, 1, 3, 4], [2, 5])
    entry = POLICIES[policy]
    for run, stage, target_time in ((teacher, "teacher", False), (student, "snapflow", True)):
        loaded = load_policy(run)
        assert (
            loaded.metadata["policy"] == policy
            and loaded.metadata["stage"] == stage
            and loaded.metadata["target_time"] is target_time
        )
        assert type(loaded.policy.model) is entry.model_class and type(loaded.processor) is entry.processor_class
        assert type(loaded.processor.config) is entry.config_class and loaded.processor.chunk_length == 4
        assert (loaded.policy.target_time_embedding is not None) is target_time
        assert loaded.processor.instructions == tuple(demonstrations.instructions.values())
        assert loaded.path.name == ("step_0000004" if stage == "teacher" else "step_0000002")
    assert json.loads((student / "history.json").read_text())["step"] == 2

    output = tmp_path / "eval"
    flags = f"--env metaworld --modes snapflow-1,teacher-2 --tasks {EVAL_TASK} --episodes 1 --n-act 4 --no-progress"
    arguments = ["eval", "--policy", str(student), "--data", str(data), "--output", str(output), *flags.split()]
    assert main(arguments) == 0
    report = json.loads((output / "report.json").read_text())
    assert (report["env"], report["tasks"], report["episodes_per_task"], report["n_act"]) == (
        "metaworld",
        [EVAL_TASK],
        1,
        4,
    )
    assert list(report["rows"]) == ["snapflow-1", "teacher-2"]
    for label, nfe in (("snapflow-1", 1), ("teacher-2", 2)):
        row = report["rows"][label]
        assert row["nfe"] == nfe and row["policy"] == recorded_path(student / "checkpoints" / "step_0000002")
        success = row["success"][EVAL_TASK]
        assert (
            success["episodes"] == 1
            and success["successes"] in (0, 1)
            and success["success_rate"] == success["successes"]
        )
        # the last episode of each task is held out (val_fraction 0.1, at least one of three): one chunk per step
        held_out = sum(demonstrations.episodes[index].length for index in (2, 5))
        offline = row["offline"]
        assert offline["samples"] == min(500, held_out) and -1 <= offline["cosine"] <= 1 and offline["mse"] > 0
        assert 0 <= offline["mse_median"] <= offline["mse_p90"] <= offline["mse_p95"]
        latency = report["latency"][label]
        assert latency["nfe"] == nfe and latency["prefix"]["repeats"] == 50 and latency["end_to_end"]["median_ms"] > 0
    assert report["latency"]["snapflow-1"]["end_to_end_speedup"] == 1.0
    assert "## Offline action error" in (output / "report.md").read_text() and "snapflow-1" in capsys.readouterr().out

    bench = tmp_path / "bench"
    flags = "--warmup 1 --repeats 2 --no-profile".split()
    assert main(["bench", "--policy", str(student), "--output", str(bench), *flags]) == 0
    timed = json.loads((bench / "bench.json").read_text())
    assert timed["subject"] == f"{policy} ({recorded_path(student)})" and timed["details"]["policy_type"] == policy
    assert timed["details"]["config"] == load_policy(student).processor.config.to_dict()
    assert timed["details"]["parameters"] == sum(
        parameter.numel() for parameter in load_policy(student).policy.parameters()
    )
    assert [entry["nfe"] for entry in timed["latency"]["modes"].values()] == [10, 5, 2, 1]
    assert timed["latency"]["repeats"] == 2 and "profile_one_step" not in timed
