"""Training built-in policies on real files: resume, atomic checkpoints, refusals, clear errors, distillation's start
and schedule. The demonstrations are synthetic (Meta-World's shapes, no simulator); the Meta-World pipeline is in
tests/evaluation/test_pipeline.py and the CLI of every built-in policy in test_builtin_policies.py."""

from __future__ import annotations

import json
import shutil

import pytest
import torch
from safetensors.torch import load_file

from snapflow.cli import main
from snapflow.policies.checkpoint import CheckpointError, load_policy
from snapflow.policies.factory import default_config
from snapflow.training.checkpoint import keep_checkpoint
from snapflow.training.recipes import DistillSettings
from snapflow.training.stages import distill, train_teacher
from tests.training.fixtures import SYNTHETIC_TASKS, TASK, TINY, synthetic_demonstrations, train_config

TINY_MLP = default_config(
    "mlp", 39, 4, list(SYNTHETIC_TASKS.values()), chunk_length=4, hidden_dim=32, time_embedding_dim=16
)
POLICIES = [pytest.param(TINY, id="minivla"), pytest.param(TINY_MLP, id="mlp")]


@pytest.fixture(scope="module")
def demonstrations(tmp_path_factory):
    return synthetic_demonstrations().save(tmp_path_factory.mktemp("demos"))


def _weights(run, step: int) -> dict[str, torch.Tensor]:
    return load_file(run / "checkpoints" / f"step_{step:07d}" / "policy.safetensors")


def _same_weights(a: dict[str, torch.Tensor], b: dict[str, torch.Tensor]) -> bool:
    return a.keys() == b.keys() and all(torch.equal(a[key], b[key]) for key in a)


@pytest.mark.parametrize("policy", POLICIES)
def test_resume_continues_exactly_where_training_stopped(demonstrations, tmp_path, policy):
    straight = train_teacher(demonstrations, tmp_path / "straight", policy, train_config(6), progress=False)
    assert straight["step"] == 6 and [entry["step"] for entry in straight["history"]] == [1, 2, 3, 4, 5, 6]
    assert [entry["step"] for entry in straight["validation"]] == [3, 6]
    # the same run, stopped after its step-3 checkpoint and resumed
    interrupted = tmp_path / "interrupted"
    train_teacher(demonstrations, interrupted, policy, train_config(6), progress=False)
    (interrupted / "latest.json").write_text(json.dumps({"checkpoint": "checkpoints/step_0000003"}))
    (interrupted / "history.json").unlink()
    shutil.rmtree(interrupted / "checkpoints" / "step_0000006")
    resumed = train_teacher(demonstrations, interrupted, policy, train_config(6), resume=True, progress=False)
    assert resumed["step"] == 6
    assert [h["loss"] for h in resumed["history"]] == [h["loss"] for h in straight["history"]]
    assert resumed["validation"] == straight["validation"]
    assert _same_weights(_weights(tmp_path / "straight", 6), _weights(interrupted, 6))
    assert json.loads((interrupted / "history.json").read_text())["history"] == resumed["history"]


KILLED_MID_CHECKPOINT = """
import os, signal, sys
from pathlib import Path

from safetensors.torch import save_file

from snapflow.policies import checkpoint as policy_checkpoint
from snapflow.training import checkpoint as training_checkpoint
from snapflow.training.stages import train_teacher
from tests.training.fixtures import TINY, train_config

writes = []


def save_file_then_die_on_the_third(tensors, path, *args, **kwargs):
    writes.append(path)
    save_file(tensors, path, *args, **kwargs)
    if len(writes) == 3:  # step 3's weights and optimizer, then the step-6 weights: half written, then SIGKILL
        data = Path(path).read_bytes()
        Path(path).write_bytes(data[: len(data) // 2])
        os.kill(os.getpid(), signal.SIGKILL)


policy_checkpoint.save_file = training_checkpoint.save_file = save_file_then_die_on_the_third
train_teacher(Path(sys.argv[1]), Path(sys.argv[2]), TINY, train_config(6), progress=False)
"""


@pytest.mark.slow
def test_a_kill_in_the_middle_of_a_checkpoint_write_loses_nothing_and_resume_matches(demonstrations, tmp_path):
    import subprocess
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parents[2]
    straight = train_teacher(demonstrations, tmp_path / "straight", TINY, train_config(6), progress=False)
    run = tmp_path / "killed"
    process = subprocess.run(
        [sys.executable, "-c", KILLED_MID_CHECKPOINT, str(demonstrations), str(run)],
        cwd=root,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert process.returncode == -9, process.stderr  # really killed, inside the checkpoint write
    partial = list((run / "checkpoints").glob(".step_0000006.partial-*"))
    assert len(partial) == 1 and not (run / "checkpoints" / "step_0000006").exists()
    assert (partial[0] / "policy.safetensors").stat().st_size < (
        run / "checkpoints" / "step_0000003" / "policy.safetensors"
    ).stat().st_size
    # the last good checkpoint is untouched and still the one a resume starts from
    assert json.loads((run / "latest.json").read_text()) == {"checkpoint": "checkpoints/step_0000003"}
    assert load_policy(run).path == run / "checkpoints" / "step_0000003"
    resumed = train_teacher(demonstrations, run, TINY, train_config(6), resume=True, progress=False)
    assert [h["loss"] for h in resumed["history"]] == [h["loss"] for h in straight["history"]]
    assert _same_weights(_weights(tmp_path / "straight", 6), _weights(run, 6))
    assert not list((run / "checkpoints").glob(".*.partial-*")), "the killed writer's leftovers are cleared"


def _files(directory) -> dict[str, tuple[int, int]]:
    """Every file under ``directory`` with its size and modification time."""
    return {
        path.relative_to(directory).as_posix(): (path.stat().st_size, path.stat().st_mtime_ns)
        for path in sorted(directory.rglob("*"))
        if path.is_file()
    }


@pytest.mark.slow
def test_a_command_into_a_run_another_holds_is_refused_and_the_run_resumes_once_its_holder_is_killed(
    demonstrations, tmp_path
):
    import os
    import signal
    import subprocess
    import sys
    import time
    from pathlib import Path

    root = Path(__file__).resolve().parents[2]
    run = tmp_path / "run"
    # 700 steps: the CLI checkpoints every 500, so the holder can be caught with a checkpoint behind it and steps to go
    train = [sys.executable, "-m", "snapflow.cli", "train", "--policy-type", "mlp", "--data", str(demonstrations)]
    train += ["--output", str(run), "--steps", "700", "--batch-size", "8", "--chunk-length", "4", "--no-progress"]
    distill_into_it = [sys.executable, "-m", "snapflow.cli", "distill", "--teacher", str(run)]
    distill_into_it += ["--data", str(demonstrations), "--output", str(run), "--no-progress"]
    environment = {**os.environ, "OMP_NUM_THREADS": "1"}  # tiny steps: more threads only fight over shared cores
    log = tmp_path / "holder.log"
    with log.open("w") as output:
        holder = subprocess.Popen(train, cwd=root, env=environment, stdout=output, stderr=subprocess.STDOUT)

    def stop_holder_once(ready) -> None:
        deadline = time.monotonic() + 300
        while not ready():
            assert holder.poll() is None and time.monotonic() < deadline, log.read_text()
            time.sleep(0.01)
        os.kill(holder.pid, signal.SIGSTOP)  # frozen mid-run, holding the run

    def holds_the_lock() -> bool:  # the holder writes its pid only once it has the lock
        try:
            return json.loads((run / ".snapflow.lock").read_text())["pid"] == holder.pid
        except (OSError, ValueError):
            return False

    def refused(command: list[str]) -> None:
        before = _files(run)
        process = subprocess.run(command, cwd=root, env=environment, capture_output=True, text=True, timeout=300)
        assert process.returncode == 2, process.stderr
        assert process.stderr.splitlines() == [
            f"snapflow {command[3]}: error: {run} is in use by another snapflow command (pid {holder.pid}, snapflow "
            "train); wait for it to finish or choose another --output"
        ]
        assert _files(run) == before, "a refused command wrote nothing"

    try:
        stop_holder_once(holds_the_lock)
        assert not (run / "latest.json").exists(), "caught before its first checkpoint: the race of issue 16"
        refused(train)
        os.kill(holder.pid, signal.SIGCONT)
        stop_holder_once((run / "latest.json").is_file)
        assert json.loads((run / "latest.json").read_text()) == {"checkpoint": "checkpoints/step_0000500"}
        refused(distill_into_it)
    finally:
        holder.kill()  # SIGKILL, stopped or not
        holder.wait()
    assert holder.returncode == -signal.SIGKILL
    resumed = subprocess.run(
        train + ["--resume"], cwd=root, env=environment, capture_output=True, text=True, timeout=300
    )
    assert resumed.returncode == 0, resumed.stderr
    assert f"resuming {run} at step 500" in resumed.stdout and "teacher trained to step 700" in resumed.stdout
    assert json.loads((run / "latest.json").read_text()) == {"checkpoint": "checkpoints/step_0000700"}
    assert json.loads((run / "history.json").read_text())["step"] == 700


def test_a_run_continues_on_another_machine_from_the_checkpoint_it_kept(demonstrations, tmp_path, capsys):
    """--keep-progress: the latest checkpoint is copied to a folder to commit; on a machine with that folder alone,
    --resume continues from it and ends with the weights of a run never interrupted."""
    kept = tmp_path / "kept"
    common = ["--data", str(demonstrations), "--steps", "4", "--batch-size", "8", "--checkpoint-every", "2"]
    common += ["--no-progress", "--keep-progress", str(kept)]
    first = tmp_path / "first"
    assert main(["train", *common, "--output", str(first)]) == 0
    assert sorted(path.name for path in kept.iterdir()) == ["kept.json", "step_0000004"], "the latest alone"
    assert _same_weights(_weights(first, 4), load_file(kept / "step_0000004" / "policy.safetensors"))
    # the first machine was lost after its step-2 checkpoint: that is what it had kept
    keep_checkpoint(first / "checkpoints" / "step_0000002", kept, {})
    # marked, to tell a continuation from a fresh start (which, with the same seed, would end with the same weights)
    state_file = kept / "step_0000002" / "trainer_state.json"
    state_file.write_text(json.dumps({**json.loads(state_file.read_text()), "wall_time_s": 1000.0}))
    second = tmp_path / "second"
    assert main(["train", *common, "--output", str(second), "--resume"]) == 0
    assert "continuing from the one kept in" in capsys.readouterr().out
    assert json.loads((second / "history.json").read_text())["wall_time_s"] > 1000, "the kept trainer state"
    assert _same_weights(_weights(first, 4), _weights(second, 4))
    assert sorted(path.name for path in kept.iterdir()) == ["kept.json", "step_0000004"]
    # without --resume a kept checkpoint is never read: a fresh output starts over
    assert main(["train", *common, "--output", str(tmp_path / "third")]) == 0
    assert "continuing from" not in capsys.readouterr().out
    assert json.loads((tmp_path / "third" / "history.json").read_text())["wall_time_s"] < 1000


def test_resume_refuses_changed_settings_and_fresh_runs_refuse_to_overwrite(demonstrations, tmp_path):
    train_teacher(demonstrations, tmp_path / "run", TINY, train_config(3), progress=False)
    with pytest.raises(CheckpointError, match=r"training settings differ from the checkpoint's in \['learning_rate'\]"):
        train_teacher(
            demonstrations, tmp_path / "run", TINY, train_config(3, learning_rate=1e-2), resume=True, progress=False
        )
    with pytest.raises(FileExistsError, match="--resume"):
        train_teacher(demonstrations, tmp_path / "run", TINY, train_config(3), progress=False)
    # nothing was written by the refused calls: the run still ends at its own step 3
    assert json.loads((tmp_path / "run" / "latest.json").read_text()) == {"checkpoint": "checkpoints/step_0000003"}
    with pytest.raises(ValueError, match=r"val_fraction must be in \[0, 1\)"):
        train_teacher(demonstrations, tmp_path / "other", TINY, train_config(3), val_fraction=1.0, progress=False)


def test_corrupt_and_mismatched_checkpoints_give_clear_errors(demonstrations, tmp_path, capsys):
    train_teacher(demonstrations, tmp_path / "run", TINY, train_config(3), progress=False)
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
    metadata = {**metadata, "policy": "transformer"}
    del metadata["config"]["expert_widht"]
    (checkpoint / "policy.json").write_text(json.dumps(metadata))
    with pytest.raises(CheckpointError, match="unknown policy 'transformer'; the built-in policies are minivla, mlp"):
        load_policy(checkpoint)
    with pytest.raises(CheckpointError, match="does not exist"):
        load_policy(tmp_path / "nowhere")


def test_distillation_starts_the_student_as_the_teacher_and_trains_only_the_expert(demonstrations, tmp_path):
    teacher = tmp_path / "teacher"
    train_teacher(demonstrations, teacher, TINY, train_config(3), progress=False)
    student = tmp_path / "student"
    state = distill(teacher, demonstrations, student, train_config(3), DistillSettings(), progress=False)
    assert state["step"] == 3 and state["validation"][-1]["consistency"] > 0
    teacher_weights, student_weights = _weights(teacher, 3), _weights(student, 3)
    assert set(student_weights) - set(teacher_weights) == {
        f"target_time_embedding.linear_{layer}.{kind}" for layer in ("in", "out") for kind in ("weight", "bias")
    }
    loaded_teacher = load_policy(teacher)
    prefix = {
        name
        for name, parameter in loaded_teacher.policy.named_parameters()
        if id(parameter) in {id(p) for p in loaded_teacher.policy.model.prefix_parameters()}
    }
    assert prefix and all(torch.equal(teacher_weights[name], student_weights[name]) for name in prefix), (
        "the prefix is frozen"
    )
    assert not torch.equal(teacher_weights["model.velocity_head.weight"], student_weights["model.velocity_head.weight"])
    assert student_weights["target_time_embedding.linear_out.weight"].abs().sum() > 0, "phi_s trained"
    saved = load_policy(student)
    assert saved.metadata["stage"] == "snapflow" and saved.metadata["teacher"] == str(
        teacher / "checkpoints" / "step_0000003"
    )
    assert saved.metadata["distill"]["alpha"] == 0.5 and saved.metadata["data"]["val_fraction"] == 0.1
    with pytest.raises(CheckpointError, match="cannot be loaded without its target-time embedding"):
        load_policy(student, target_time=False)


def test_a_scheduled_target_is_raised_in_equal_stages_and_logged(demonstrations, tmp_path):
    teacher = tmp_path / "teacher"
    train_teacher(demonstrations, teacher, TINY, train_config(3), progress=False)
    state = distill(
        teacher,
        demonstrations,
        tmp_path / "student",
        train_config(4),
        DistillSettings(target_steps=(2, 4)),
        progress=False,
    )
    assert [entry["target_steps"] for entry in state["history"]] == [2, 2, 4, 4]
    saved = json.loads((tmp_path / "student" / "checkpoints" / "step_0000004" / "policy.json").read_text())
    assert saved["distill"]["target_steps"] == [2, 4]
