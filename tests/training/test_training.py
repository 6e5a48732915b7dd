"""Training, checkpoints and the whole Meta-World pipeline on one task, on real files."""

from __future__ import annotations

import json

import pytest
import torch
from safetensors.torch import load_file

from snapflow.cli import main
from snapflow.data.collect import collect_demonstrations
from snapflow.experiments.metaworld import distill, train_teacher
from snapflow.training.distill import DistillSettings
from snapflow.policies.minivla import MiniVLAConfig
from snapflow.training.checkpoint import CheckpointError, load_policy
from snapflow.training.trainer import TrainConfig

TINY = MiniVLAConfig(chunk_length=4, prefix_width=32, expert_width=32, num_layers=1, num_heads=2, head_dim=16)
TASK = "drawer-close-v3"


@pytest.fixture(scope="module")
def demonstrations(tmp_path_factory):
    directory = tmp_path_factory.mktemp("demos")
    collect_demonstrations([TASK], 4, progress=False).save(directory)
    return directory


def _config(steps: int, **changes) -> TrainConfig:
    return TrainConfig(steps=steps, batch_size=8, warmup_steps=2, log_every=1, validate_every=3, checkpoint_every=3, **changes)


def test_resume_continues_exactly_where_training_stopped(demonstrations, tmp_path):
    straight = train_teacher(demonstrations, tmp_path / "straight", TINY, _config(6), progress=False)
    # the same run, stopped after its step-3 checkpoint and resumed
    interrupted = tmp_path / "interrupted"
    train_teacher(demonstrations, interrupted, TINY, _config(6), progress=False)
    (interrupted / "latest.json").write_text(json.dumps({"checkpoint": "checkpoints/step_0000003"}))
    for name in ("history.json",):
        (interrupted / name).unlink()
    import shutil

    shutil.rmtree(interrupted / "checkpoints" / "step_0000006")
    resumed = train_teacher(demonstrations, interrupted, TINY, _config(6), resume=True, progress=False)
    assert resumed["step"] == 6
    assert [h["loss"] for h in resumed["history"]] == [h["loss"] for h in straight["history"]]
    a = load_file(tmp_path / "straight" / "checkpoints" / "step_0000006" / "policy.safetensors")
    b = load_file(interrupted / "checkpoints" / "step_0000006" / "policy.safetensors")
    assert a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)


KILLED_MID_CHECKPOINT = """
import os, signal, sys
from pathlib import Path

from safetensors.torch import save_file

from snapflow.experiments.metaworld import train_teacher
from snapflow.training import checkpoint
from tests.test_training import TINY, _config

writes = []


def save_file_then_die_on_the_third(tensors, path, *args, **kwargs):
    writes.append(path)
    save_file(tensors, path, *args, **kwargs)
    if len(writes) == 3:  # the step-6 checkpoint's weights: leave the file half written, then SIGKILL
        data = Path(path).read_bytes()
        Path(path).write_bytes(data[: len(data) // 2])
        os.kill(os.getpid(), signal.SIGKILL)


checkpoint.save_file = save_file_then_die_on_the_third
train_teacher(Path(sys.argv[1]), Path(sys.argv[2]), TINY, _config(6), progress=False)
"""


def test_a_kill_in_the_middle_of_a_checkpoint_write_loses_nothing_and_resume_matches(demonstrations, tmp_path):
    import subprocess
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    straight = train_teacher(demonstrations, tmp_path / "straight", TINY, _config(6), progress=False)
    run = tmp_path / "killed"
    process = subprocess.run([sys.executable, "-c", KILLED_MID_CHECKPOINT, str(demonstrations), str(run)], cwd=root,
                             capture_output=True, text=True, timeout=600)
    assert process.returncode == -9, process.stderr  # really killed, inside the checkpoint write
    partial = list((run / "checkpoints").glob(".step_0000006.partial-*"))
    assert len(partial) == 1 and not (run / "checkpoints" / "step_0000006").exists()
    # the last good checkpoint is untouched and still the one a resume starts from
    assert json.loads((run / "latest.json").read_text()) == {"checkpoint": "checkpoints/step_0000003"}
    load_policy(run)
    resumed = train_teacher(demonstrations, run, TINY, _config(6), resume=True, progress=False)
    assert [h["loss"] for h in resumed["history"]] == [h["loss"] for h in straight["history"]]
    a = load_file(tmp_path / "straight" / "checkpoints" / "step_0000006" / "policy.safetensors")
    b = load_file(run / "checkpoints" / "step_0000006" / "policy.safetensors")
    assert a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)
    assert not list((run / "checkpoints").glob(".*.partial-*")), "the killed writer's leftovers are cleared"


def test_resume_refuses_changed_settings_and_fresh_runs_refuse_to_overwrite(demonstrations, tmp_path):
    train_teacher(demonstrations, tmp_path / "run", TINY, _config(3), progress=False)
    with pytest.raises(CheckpointError, match="learning_rate"):
        train_teacher(demonstrations, tmp_path / "run", TINY, _config(3, learning_rate=1e-2), resume=True, progress=False)
    with pytest.raises(FileExistsError, match="--resume"):
        train_teacher(demonstrations, tmp_path / "run", TINY, _config(3), progress=False)


def test_corrupt_and_mismatched_checkpoints_give_clear_errors(demonstrations, tmp_path, capsys):
    train_teacher(demonstrations, tmp_path / "run", TINY, _config(3), progress=False)
    checkpoint = tmp_path / "run" / "checkpoints" / "step_0000003"
    weights = checkpoint / "policy.safetensors"
    original = weights.read_bytes()

    weights.write_bytes(original[: len(original) // 2])
    with pytest.raises(CheckpointError, match="corrupt or not a safetensors file"):
        load_policy(tmp_path / "run")
    assert main(["eval", "--policy", str(tmp_path / "run"), "--tasks", TASK, "--episodes", "1", "--no-progress"]) == 2
    assert "corrupt" in capsys.readouterr().err

    weights.write_bytes(original)
    metadata = json.loads((checkpoint / "policy.json").read_text())
    metadata["config"]["expert_width"] = 64
    (checkpoint / "policy.json").write_text(json.dumps(metadata))
    with pytest.raises(CheckpointError, match="shape mismatch"):
        load_policy(checkpoint)
    metadata["config"]["expert_widht"] = 64
    (checkpoint / "policy.json").write_text(json.dumps(metadata))
    with pytest.raises(CheckpointError, match="expert_widht"):
        load_policy(checkpoint)
    with pytest.raises(CheckpointError, match="does not exist"):
        load_policy(tmp_path / "nowhere")


def test_collect_train_distill_eval_on_one_task(demonstrations, tmp_path, capsys):
    teacher = tmp_path / "teacher"
    train_teacher(demonstrations, teacher, TINY, _config(6), progress=False)
    student = tmp_path / "student"
    state = distill(teacher, demonstrations, student, _config(3), DistillSettings(), progress=False)
    assert state["step"] == 3 and state["validation"][-1]["consistency"] > 0
    # the student starts as the teacher: the frozen prefix is unchanged, phi_s is new
    teacher_weights = load_file(teacher / "checkpoints" / "step_0000006" / "policy.safetensors")
    student_weights = load_file(student / "checkpoints" / "step_0000003" / "policy.safetensors")
    assert torch.equal(teacher_weights["model.prefix_layers.0.attention.qkv.weight"], student_weights["model.prefix_layers.0.attention.qkv.weight"])
    assert "target_time_embedding.linear_out.weight" in student_weights
    assert not torch.equal(teacher_weights["model.velocity_head.weight"], student_weights["model.velocity_head.weight"])

    output = tmp_path / "eval"
    code = main(["eval", "--policy", str(student), "--modes", "snapflow-1,teacher-2", "--tasks", TASK, "--episodes", "1",
                 "--n-act", "4", "--data", str(demonstrations), "--output-dir", str(output), "--no-progress"])
    assert code == 0
    report = json.loads((output / "report.json").read_text())
    for label in ("snapflow-1", "teacher-2"):
        row = report["rows"][label]
        assert row["success"][TASK]["episodes"] == 1 and row["offline"]["samples"] > 0
        assert -1 <= row["offline"]["cosine"] <= 1 and row["offline"]["mse_p95"] >= row["offline"]["mse_median"]
    assert report["latency"]["teacher-2"]["nfe"] == 2
    assert (output / "success.png").is_file() and (output / "latency.png").is_file()
    assert "Closed-loop success" in (output / "report.md").read_text()
    assert "snapflow-1" in capsys.readouterr().out


def test_a_scheduled_target_is_raised_in_equal_stages_and_logged(demonstrations, tmp_path):
    teacher = tmp_path / "teacher"
    train_teacher(demonstrations, teacher, TINY, _config(3), progress=False)
    state = distill(teacher, demonstrations, tmp_path / "student", _config(4), DistillSettings(target_steps=(2, 4)), progress=False)
    assert [entry["target_steps"] for entry in state["history"]] == [2, 2, 4, 4]
    saved = json.loads((tmp_path / "student" / "checkpoints" / "step_0000004" / "policy.json").read_text())
    assert saved["distill"]["target_steps"] == [2, 4]


def test_bench_targets_times_every_target_on_the_same_batch_and_writes_its_files(demonstrations, tmp_path, capsys):
    teacher = tmp_path / "teacher"
    train_teacher(demonstrations, teacher, TINY, _config(3), progress=False)
    output = tmp_path / "cost"
    assert main(["bench-targets", "--teacher", str(teacher), "--data", str(demonstrations), "--targets", "euler:2", "euler:2,8", "bootstrap:4",
                 "--batch-size", "8", "--warmup", "1", "--repeats", "4", "--output-dir", str(output), "--no-progress"]) == 0
    result = json.loads((output / "training_cost.json").read_text())
    assert [row["option"] for row in result["rows"]] == ["euler-2", "euler-2-8", "bootstrap-4"]
    assert [row["teacher_passes_per_row"] for row in result["rows"]] == [2.0, 5.0, 2.0]
    assert result["rows"][0]["relative_to_first"] == 1.0 and result["repeats"] == 4 and result["batch_size"] == 8
    assert all(0 < row["step_ms_median"] <= row["step_ms_p90"] for row in result["rows"])
    assert "| bootstrapped (K -> 4) | 2 + 1 |" in (output / "training_cost.md").read_text() and "K = 2 -> 8" in capsys.readouterr().out
    assert main(["bench-targets", "--teacher", str(teacher), "--data", str(demonstrations), "--targets", "euler:two",
                 "--output-dir", str(output), "--no-progress"]) == 2
    assert "target steps must be integers" in capsys.readouterr().err


def test_unknown_task_is_a_clear_cli_error(capsys):
    assert main(["collect", "--tasks", "reach-v3,teleport-v3", "--episodes", "1", "--output", "unused", "--no-progress"]) == 2
    assert "unknown Meta-World task(s) ['teleport-v3']" in capsys.readouterr().err


def test_camera_images_flow_through_collect_train_and_closed_loop(tmp_path):
    from dataclasses import replace

    from snapflow.data import Demonstrations
    from snapflow.envs.metaworld import MetaWorldEnv

    env = MetaWorldEnv(TASK, "eval", image_size=32)
    try:
        first = env.reset(0)
        assert first.image.shape == (32, 32, 3) and first.image.dtype == "uint8" and first.image.std() > 0
        assert env.step(first.state[:4] * 0, render=False)[0].image is None
    finally:
        env.close()

    collect_demonstrations([TASK], 2, image_size=32, progress=False).save(tmp_path / "demos")
    demonstrations = Demonstrations.load(tmp_path / "demos")
    assert demonstrations.images.shape == (len(demonstrations.states), 32, 32, 3)
    config = replace(TINY, use_image=True, image_size=32, patch_size=16)
    train_teacher(tmp_path / "demos", tmp_path / "teacher", config, _config(3), progress=False)
    loaded = load_policy(tmp_path / "teacher")
    assert loaded.processor.config.use_image and loaded.processor.config.num_patches == 4
    code = main(["eval", "--policy", str(tmp_path / "teacher"), "--modes", "naive", "--tasks", TASK, "--episodes", "1",
                 "--output-dir", str(tmp_path / "eval"), "--no-progress"])
    assert code == 0
    assert json.loads((tmp_path / "eval" / "report.json").read_text())["rows"]["naive-1"]["success"][TASK]["episodes"] == 1


def test_demo_chains_every_stage_into_one_report_and_resumes(tmp_path):
    from snapflow.experiments.metaworld import DemoPreset, run_demo

    preset = DemoPreset(tasks=(TASK,), episodes_per_task=3, policy=TINY, teacher=_config(4), student=_config(2), eval_episodes=1)
    report = run_demo(preset, tmp_path, progress=False)
    assert set(report["rows"]) == {"teacher 10-NFE", "naive 1-NFE", "SnapFlow 1-NFE"}
    assert report["rows"]["SnapFlow 1-NFE"]["success"]["mean"]["episodes"] == 1
    assert set(report["timings"]) == {"collect_s", "teacher_s", "distill_s", "evaluate_s", "total_s"}
    for name in ("report.json", "report.md", "success.png", "latency.png"):
        assert (tmp_path / name).is_file()
    markdown = (tmp_path / "report.md").read_text()
    assert "| **mean** |" in markdown and "denoising speedup" in markdown
    # an interrupted demo continues from what it saved: both runs are already complete, so nothing is redone
    resumed = run_demo(preset, tmp_path, progress=False, resume=True)
    assert resumed["rows"]["teacher 10-NFE"]["success"] == report["rows"]["teacher 10-NFE"]["success"]
