"""The Meta-World pipeline on real files: collect -> train -> distill -> eval on one task, camera images through every
stage, and ``snapflow demo`` chaining it all into one report (simulator tests: slow)."""

from __future__ import annotations

import json

import pytest

from snapflow.cli import main
from snapflow.data.chunks import ChunkData
from snapflow.data.demonstrations import Demonstrations
from snapflow.evaluation.pipeline import labelled_runs
from snapflow.evaluation.results import EvaluationReport
from snapflow.flow.modes import NAIVE_1, SNAPFLOW_1, TEACHER_10
from snapflow.policies.checkpoint import load_policy
from snapflow.reporting.files import recorded_path
from snapflow.training.recipes import DistillSettings
from snapflow.training.stages import distill, train_teacher
from tests.evaluation.figures import CYCLE, assert_figure
from tests.training.fixtures import TASK, TINY, collected, train_config


def test_unknown_task_is_a_clear_cli_error(capsys):
    assert (
        main(["collect", "--tasks", "reach-v3,teleport-v3", "--episodes", "1", "--output", "unused", "--no-progress"])
        == 2
    )
    assert "unknown metaworld task(s) ['teleport-v3']" in capsys.readouterr().err
    # the task is checked before any policy loads
    assert main(["eval", "--policy", "nowhere", "--env", "metaworld", "--tasks", "teleport-v3", "--no-progress"]) == 2
    assert "unknown metaworld task(s) ['teleport-v3']" in capsys.readouterr().err
    assert main(["eval", "--policy", "nowhere", "--env", "metaworld", "--tasks", "reach-v3", "--no-progress"]) == 2
    assert "no folder nowhere; hub ids are owner/name" in capsys.readouterr().err


def test_runs_are_labelled_by_their_mode_then_by_as_much_of_their_path_as_tells_them_apart():
    teacher, student = object(), object()  # the labels need nothing of the policies
    assert labelled_runs({"runs/student": (student, [SNAPFLOW_1])}) == [("snapflow-1", student, SNAPFLOW_1)]
    two = {
        "runs/teacher/lerobot_policy": (teacher, [TEACHER_10, NAIVE_1]),
        "b/student/lerobot_policy": (student, [SNAPFLOW_1]),
    }
    assert [label for label, _, _ in labelled_runs(two)] == [
        "teacher/lerobot_policy teacher-10",
        "teacher/lerobot_policy naive-1",
        "student/lerobot_policy snapflow-1",
    ]


@pytest.mark.slow
def test_collect_train_distill_eval_on_one_task(tmp_path_factory, tmp_path, capsys):
    demonstrations = collected(tmp_path_factory)
    teacher, student = tmp_path / "teacher", tmp_path / "student"
    train_teacher(demonstrations, teacher, TINY, train_config(6), progress=False)
    state = distill(teacher, demonstrations, student, train_config(3), DistillSettings(), progress=False)
    assert state["step"] == 3 and state["validation"][-1]["consistency"] > 0
    assert load_policy(teacher).metadata["data"]["env"] == "metaworld"

    output = tmp_path / "eval"
    code = main(
        [
            "eval",
            "--policy",
            str(student),
            "--modes",
            "snapflow-1,teacher-2",
            "--tasks",
            TASK,
            "--episodes",
            "1",
            "--n-act",
            "4",
            "--data",
            str(demonstrations),
            "--output",
            str(output),
            "--no-progress",
        ]
    )
    assert code == 0
    report = json.loads((output / "report.json").read_text())
    assert (report["env"], report["tasks"], report["episodes_per_task"], report["n_act"]) == ("metaworld", [TASK], 1, 4)
    loaded = load_policy(student)
    data = Demonstrations.load(demonstrations)
    held_out = len(ChunkData(data, data.split(loaded.val_fraction)[1], loaded.processor))
    for label, nfe in (("snapflow-1", 1), ("teacher-2", 2)):
        row = report["rows"][label]
        assert row["policy"] == recorded_path(loaded.path) and row["mode"] == label and row["nfe"] == nfe
        success = row["success"][TASK]
        assert (
            success["episodes"] == 1
            and success["successes"] in (0, 1)
            and success["success_rate"] == success["successes"]
        )
        assert row["success"]["mean"] == success
        offline = row["offline"]
        assert offline["samples"] == min(500, held_out) > 0
        assert -1 <= offline["cosine"] <= 1 and 0 <= offline["mse_median"] <= offline["mse_p90"] <= offline["mse_p95"]
        assert report["latency"][label]["nfe"] == nfe and report["latency"][label]["prefix"]["repeats"] == 50
    assert report["latency"]["snapflow-1"]["end_to_end_speedup"] == 1.0  # the first row is the reference
    assert_figure(output / "success.png", (6, 4), {CYCLE[0]: 0.0003, CYCLE[1]: 0.0003})
    assert_figure(output / "latency.png", (6, 3.5), {CYCLE[1]: 0.005})
    markdown = (output / "report.md").read_text()
    assert "# SnapFlow on Meta-World (1 task)" in markdown and "## Closed-loop success" in markdown  # not "MT10"
    assert f"| {TASK} | {100 * report['rows']['snapflow-1']['success'][TASK]['success_rate']:.1f}% (" in markdown
    assert "| snapflow-1 | teacher-2 |" in capsys.readouterr().out


@pytest.mark.slow
def test_camera_images_flow_through_collect_train_and_closed_loop(tmp_path_factory, tmp_path):
    from dataclasses import replace

    from snapflow.envs.metaworld import MetaWorldEnv

    env = MetaWorldEnv(TASK, "eval", image_size=32)
    try:
        first = env.reset(0)
        assert first.image.shape == (32, 32, 3) and first.image.dtype == "uint8" and first.image.std() > 0
        assert env.step(first.state[:4] * 0, render=False)[0].image is None
    finally:
        env.close()

    directory = collected(tmp_path_factory, episodes_per_task=2, image_size=32)
    demonstrations = Demonstrations.load(directory)
    assert demonstrations.images.shape == (len(demonstrations.states), 32, 32, 3) and demonstrations.images.std() > 0
    config = replace(TINY, use_image=True, image_size=32, patch_size=16)
    train_teacher(directory, tmp_path / "teacher", config, train_config(3), progress=False)
    loaded = load_policy(tmp_path / "teacher")
    assert (
        loaded.processor.config.use_image
        and loaded.processor.config.image_tokens == 4
        and loaded.processor.image_size == 32
    )
    code = main(
        [
            "eval",
            "--policy",
            str(tmp_path / "teacher"),
            "--modes",
            "naive",
            "--tasks",
            TASK,
            "--episodes",
            "1",
            "--output",
            str(tmp_path / "eval"),
            "--no-progress",
        ]
    )
    assert code == 0
    report = json.loads((tmp_path / "eval" / "report.json").read_text())
    assert report["rows"]["naive-1"]["success"][TASK]["episodes"] == 1 and "offline" not in report["rows"]["naive-1"]


@pytest.mark.slow
def test_demo_chains_every_stage_into_one_report_and_resumes(tmp_path):
    from snapflow.jobs.demo import DemoPreset, run_demo

    preset = DemoPreset(
        tasks=(TASK,),
        episodes_per_task=3,
        policy=TINY,
        teacher=train_config(4, time_distribution="beta:1.5"),
        student=train_config(2),
        eval_episodes=1,
    )
    report = run_demo(preset, tmp_path, progress=False)
    # the preset's teacher times: in the teacher's checkpoint, its student's, and the report's preset
    assert [load_policy(tmp_path / run).time_distribution for run in ("teacher", "snapflow")] == ["beta:1.5"] * 2
    assert isinstance(report, EvaluationReport)
    assert list(report.rows) == ["teacher 10-NFE", "naive 1-NFE", "SnapFlow 1-NFE"]
    assert [row.nfe for row in report.rows.values()] == [10, 1, 1]
    assert report.rows["SnapFlow 1-NFE"].success["mean"].episodes == 1
    assert (
        report.rows["naive 1-NFE"].policy
        == report.rows["teacher 10-NFE"].policy
        != report.rows["SnapFlow 1-NFE"].policy
    )
    assert all(row.offline is not None and row.offline.samples > 0 for row in report.rows.values())
    assert list(report.timings) == ["collect_s", "teacher_s", "distill_s", "evaluate_s", "total_s"]
    assert report.timings["total_s"] >= sum(value for key, value in report.timings.items() if key != "total_s") - 1e-6
    written = json.loads((tmp_path / "report.json").read_text())
    assert written == json.loads(json.dumps(report.to_dict()))
    assert written["preset"]["policy"] == TINY.to_dict() and written["preset"]["tasks"] == [TASK]
    assert written["preset"]["teacher"]["time_distribution"] == "beta:1.5"
    assert_figure(tmp_path / "success.png", (6, 4), {CYCLE[0]: 0.0003, CYCLE[1]: 0.0003, CYCLE[2]: 0.0003})
    assert_figure(tmp_path / "latency.png", (6, 3.5), {CYCLE[1]: 0.005})
    markdown = (tmp_path / "report.md").read_text()
    assert "| **mean** |" in markdown and "denoising speedup" in markdown and "## Wall time" in markdown
    # an interrupted demo continues from what it saved: both runs are already complete, so nothing is redone
    stamps = {path: path.stat().st_mtime_ns for path in tmp_path.rglob("*.safetensors")}
    resumed = run_demo(preset, tmp_path, progress=False, resume=True)
    assert stamps == {path: path.stat().st_mtime_ns for path in tmp_path.rglob("*.safetensors")}, (
        "no checkpoint was rewritten"
    )
    assert resumed.rows["teacher 10-NFE"].success == report.rows["teacher 10-NFE"].success
    assert resumed.rows["SnapFlow 1-NFE"].offline == report.rows["SnapFlow 1-NFE"].offline
