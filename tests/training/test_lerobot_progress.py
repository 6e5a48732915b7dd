"""A lerobot-train run's progress kept as it goes and put back on another machine
(:mod:`snapflow.training.lerobot_progress`), on run folders laid out as lerobot-train 0.6.1 lays them out: a
``checkpoints/<step>/`` folder (``pretrained_model/``, ``training_state/``) saved whole, then ``checkpoints/last``
pointed at it. ``tests/jobs/test_sweep_lerobot.py`` resumes a real lerobot-train run from what is kept."""

from __future__ import annotations

import json
import os
import time
from pathlib import Path

from snapflow.training.checkpoint import keep_checkpoint
from snapflow.training.lerobot_progress import (
    ELAPSED,
    STUDENT_FOLDER,
    CheckpointKeeper,
    elapsed_at,
    install_kept_progress,
    newest_checkpoint,
)


def save(output: Path, step: int, student: Path) -> Path:
    """A checkpoint as lerobot-train saves one: whole first, then marked last."""
    checkpoint = output / "checkpoints" / f"{step:06d}"
    (checkpoint / "training_state").mkdir(parents=True)
    (checkpoint / "training_state" / "training_step.json").write_text(json.dumps({"step": step}))
    (checkpoint / "pretrained_model").mkdir()
    config = {"type": "snapflow_smolvla", "vlm_model_name": str(student.resolve() / "smolvlm")}
    (checkpoint / "pretrained_model" / "config.json").write_text(json.dumps(config))
    (checkpoint / "pretrained_model" / "model.safetensors").write_bytes(bytes([step]) * 16)
    last = output / "checkpoints" / "last"
    if last.is_symlink():
        last.unlink()
    last.symlink_to(checkpoint.name)
    return checkpoint


RUN = {"flags": ["--steps=8"], "distill": {"alpha": 0.5}, "weights": "digest"}  # what lerobot_train_run says


def test_each_checkpoint_marked_last_is_kept_and_a_lost_run_folder_gets_the_newest_back(tmp_path):
    here, kept = tmp_path / "machine-1" / "run", tmp_path / "records" / "checkpoint"
    output, student = here / "lerobot-train", here / "student"
    assert newest_checkpoint(output) is None
    with CheckpointKeeper(output, kept, student, RUN) as keeper:
        save(output, 2, student)
        keeper.keep_newest()  # what its watch does every few seconds
        assert json.loads((kept / "kept.json").read_text()) == {"checkpoint": "step_000002", "run": RUN}
        save(output, 4, student)
        (output / "checkpoints" / "000006" / "training_state").mkdir(parents=True)  # being saved: not marked yet
    # leaving keeps the newest once more: the run's last checkpoint is not lost to the time between two looks
    assert json.loads((kept / "kept.json").read_text()) == {"checkpoint": "step_000004", "run": RUN}
    assert sorted(path.name for path in kept.iterdir()) == ["kept.json", "step_000004"], "the previous one removed"
    kept_config = (kept / "step_000004" / "pretrained_model" / "config.json").read_text()
    assert str(tmp_path) not in kept_config and f"{STUDENT_FOLDER}/smolvlm" in kept_config, "no path of this machine"

    elsewhere = tmp_path / "machine-2" / "run"  # another clone: the run folder is gone, the student written again
    other_run = {**RUN, "flags": ["--steps=16"]}
    assert not install_kept_progress(kept, elsewhere / "lerobot-train", elsewhere / "student", other_run)
    assert not (elsewhere / "lerobot-train").exists(), "another run's progress is never resumed"
    assert install_kept_progress(kept, elsewhere / "lerobot-train", elsewhere / "student", RUN)
    installed = newest_checkpoint(elsewhere / "lerobot-train")
    assert installed == elsewhere / "lerobot-train" / "checkpoints" / "000004"
    config = json.loads((installed / "pretrained_model" / "config.json").read_text())
    assert config["vlm_model_name"] == str((elsewhere / "student").resolve() / "smolvlm")
    assert (installed / "pretrained_model" / "model.safetensors").read_bytes() == bytes([4]) * 16
    assert json.loads((installed / "training_state" / "training_step.json").read_text()) == {"step": 4}
    assert os.readlink(elsewhere / "lerobot-train" / "checkpoints" / "last") == "000004"


def test_a_finished_runs_kept_policy_or_nothing_kept_installs_nothing(tmp_path):
    output, student, kept = tmp_path / "run" / "lerobot-train", tmp_path / "run" / "student", tmp_path / "kept"
    assert not install_kept_progress(kept, output, student, RUN)
    policy = save(tmp_path / "finished", 8, student) / "pretrained_model"
    keep_checkpoint(policy, kept, {"job": {}, "finished": True})
    assert not install_kept_progress(kept, output, student, RUN)
    assert not output.exists()
    with CheckpointKeeper(output, kept, student, RUN):
        pass  # a run that saved nothing leaves the finished policy kept as it was
    assert json.loads((kept / "kept.json").read_text())["checkpoint"] == "pretrained_model"


def test_a_runs_training_time_counts_every_attempt_on_every_machine(tmp_path):
    """lerobot-train keeps no time across attempts: each checkpoint is stamped with the run's time up to it, and an
    attempt resumed from one (here, or installed from what was kept elsewhere) counts on from there."""
    output, student, kept = tmp_path / "run" / "lerobot-train", tmp_path / "run" / "student", tmp_path / "kept"
    with CheckpointKeeper(output, kept, student, RUN) as first:
        first.began -= 100.0  # an attempt that began 100 s ago
        checkpoint = save(output, 2, student)
    saved_after = json.loads((checkpoint / "training_state" / ELAPSED).read_text())["seconds"]
    assert 100.0 <= saved_after < 100.0 + 60.0, "stamped with the attempt's time up to the checkpoint's saving"
    assert elapsed_at(kept / "step_000002") == saved_after, "the stamp travels with the kept progress"

    elsewhere = tmp_path / "machine-2" / "run"
    assert install_kept_progress(kept, elsewhere / "lerobot-train", elsewhere / "student", RUN)
    began = time.time()
    with CheckpointKeeper(elsewhere / "lerobot-train", None, elsewhere / "student", RUN) as second:
        assert second.before == saved_after, "the resumed attempt counts on from its checkpoint's time"
        later = save(elsewhere / "lerobot-train", 4, elsewhere / "student")
    assert saved_after <= elapsed_at(later) <= saved_after + time.time() - began
    assert saved_after + time.time() - began >= second.elapsed >= elapsed_at(later)
    assert not (tmp_path / "machine-2" / "kept").exists(), "no kept folder given: stamped, nothing kept"
    assert elapsed_at(save(tmp_path / "old", 2, student)) == 0.0, "a checkpoint saved before stamps: time unknown"


def test_an_attempt_cut_before_stamping_its_last_checkpoint_loses_no_time(tmp_path):
    """A machine's end may come in the seconds between lerobot-train saving a checkpoint and the keeper stamping it:
    the next attempt reads its time off the newest stamped checkpoint and the time between their savings."""
    output, student = tmp_path / "run" / "lerobot-train", tmp_path / "run" / "student"
    stamped = save(output, 2, student)
    (stamped / "training_state" / ELAPSED).write_text(json.dumps({"seconds": 100.0}))
    cut = save(output, 4, student)  # saved 30 s after step 2, never stamped
    saved = time.time() - 600.0
    os.utime(stamped / "training_state" / "training_step.json", (saved, saved))
    os.utime(cut / "training_state" / "training_step.json", (saved + 30.0, saved + 30.0))
    with CheckpointKeeper(output, None, student, RUN) as resumed:
        assert resumed.before == 130.0, "step 2's 100 s and the 30 s to step 4"
    assert elapsed_at(cut) == 130.0, "stamped as it was read, not as this attempt's start"
