"""A built-in teacher's flow-matching time distribution (issue 76): it reaches the teacher's objective and its draws,
its checkpoint records it (one written before reads as uniform), `snapflow distill` draws the teacher's own for the
student's flow-matching rows, and a student's training or a LeRobot teacher refuses one. Real files and runs of a
tiny MiniVLA on synthetic demonstrations; the draws against the formulas written out here."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys

import pytest
import torch

from snapflow.errors import InvalidInputError
from snapflow.families import StudentRun, family_of
from snapflow.families.base import Source
from snapflow.policies.checkpoint import CheckpointError, load_policy
from snapflow.reporting.records import as_record
from snapflow.training.config import TEACHER_TRAINING, TrainConfig
from snapflow.training.recipes import DistillSettings
from snapflow.training.stages import distill, teacher_objective, train_teacher
from tests.training.fixtures import TINY, synthetic_demonstrations, train_config

COUNT = 2048


@pytest.fixture(scope="module")
def demonstrations(tmp_path_factory):
    return synthetic_demonstrations().save(tmp_path_factory.mktemp("demos"))


def _expected(distribution: str) -> torch.Tensor:
    """The times each distribution's formula makes of the generator's uniforms u (t = 1 the noise)."""
    u = torch.rand(COUNT, generator=torch.Generator().manual_seed(7))
    beta = 0.001 + 0.999 * u ** (1 / 1.5)  # Beta(1.5, 1) by its inverse CDF, u ** (1 / a), as LeRobot offsets it
    return {"uniform": u, "beta:1.5": beta, "shift:4": 4 * beta / (1 + 3 * beta)}[distribution]


def _drawn(sampler) -> torch.Tensor:
    return sampler(COUNT, generator=torch.Generator().manual_seed(7))


def _checkpoint(run):
    return json.loads((run / "checkpoints" / "step_0000001" / "policy.json").read_text())


@pytest.mark.parametrize("distribution", ["uniform", "beta:1.5", "shift:4"])
def test_the_teachers_objective_is_flow_matching_at_the_configured_times(distribution):
    objective = teacher_objective(TrainConfig(time_distribution=distribution))
    assert objective.alpha == 1.0, "a teacher trains on flow matching alone"
    torch.testing.assert_close(_drawn(objective.time_sampler), _expected(distribution))


def test_the_setting_is_recorded_only_where_it_is_not_the_old_uniform():
    """A record of a TrainConfig left at uniform is what it was before the setting existed (committed sweep records
    and resumable runs stay valid); another is recorded, written one way."""
    assert "time_distribution" not in as_record(TEACHER_TRAINING)
    assert TEACHER_TRAINING.time_distribution == "uniform"
    assert as_record(TrainConfig(time_distribution="beta:1.50"))["time_distribution"] == "beta:1.5"
    with pytest.raises(InvalidInputError, match="TrainConfig.time_distribution: unknown time distribution 'normal'"):
        TrainConfig(time_distribution="normal")


def test_a_teacher_trains_on_its_distribution_and_its_checkpoint_records_it(demonstrations, tmp_path):
    """One step from the same seed: beta:1.5 and shift:1 (the same distribution, written two ways) take the same
    step, uniform another; each checkpoint names its own, and opens with a sampler that draws it."""
    losses = {}
    for distribution in ("beta:1.5", "shift:1", "uniform"):
        run = tmp_path / distribution.replace(":", "-")
        state = train_teacher(
            demonstrations, run, TINY, train_config(1, time_distribution=distribution), progress=False
        )
        losses[distribution] = state["history"][0]["loss"]
        assert _checkpoint(run)["time_distribution"] == distribution
        assert load_policy(run).time_distribution == distribution
    assert losses["beta:1.5"] == losses["shift:1"] != losses["uniform"]
    torch.testing.assert_close(_drawn(load_policy(tmp_path / "beta-1.5").time_sampler), _expected("beta:1.5"))
    # a run resumed under another distribution is refused by name, as any changed training setting
    with pytest.raises(CheckpointError, match=r"differ from the checkpoint's in \['time_distribution'\]"):
        train_teacher(demonstrations, tmp_path / "beta-1.5", TINY, train_config(1), resume=True, progress=False)


def test_a_checkpoint_from_before_the_setting_reads_as_uniform_and_a_broken_one_is_refused(demonstrations, tmp_path):
    run = tmp_path / "teacher"
    train_teacher(demonstrations, run, TINY, train_config(1), progress=False)
    old = tmp_path / "old"
    shutil.copytree(run / "checkpoints" / "step_0000001", old)
    metadata = json.loads((old / "policy.json").read_text())
    del metadata["time_distribution"]  # as every teacher wrote it before
    (old / "policy.json").write_text(json.dumps(metadata))
    opened = load_policy(old)
    assert opened.time_distribution == "uniform"
    torch.testing.assert_close(_drawn(opened.time_sampler), _expected("uniform"), rtol=0, atol=0)
    (old / "policy.json").write_text(json.dumps({**metadata, "time_distribution": "beta:-1"}))
    with pytest.raises(CheckpointError, match="policy.json: invalid field: beta:A takes a positive, finite A"):
        load_policy(old)


def test_distill_draws_the_teachers_own_distribution_for_the_students_flow_matching_rows(demonstrations, tmp_path):
    """One teacher's weights under three records: the students of beta:1.5 and shift:1 (one distribution) take the
    same first step, the uniform one's another, and each student records its teacher's distribution."""
    teacher = tmp_path / "teacher"
    train_teacher(demonstrations, teacher, TINY, train_config(1), progress=False)
    losses = {}
    for distribution in ("beta:1.5", "shift:1", "uniform"):
        copy = tmp_path / f"teacher-{distribution.replace(':', '-')}"
        shutil.copytree(teacher / "checkpoints" / "step_0000001", copy)
        metadata = json.loads((copy / "policy.json").read_text())
        (copy / "policy.json").write_text(json.dumps({**metadata, "time_distribution": distribution}))
        student = tmp_path / f"student-{distribution.replace(':', '-')}"
        state = distill(copy, demonstrations, student, train_config(1), DistillSettings(), progress=False)
        losses[distribution] = state["history"][0]["loss"]
        assert _checkpoint(student)["time_distribution"] == distribution
        assert load_policy(student).time_distribution == distribution
    assert losses["beta:1.5"] == losses["shift:1"] != losses["uniform"]


def test_a_students_training_and_a_lerobot_teacher_refuse_a_distribution(demonstrations, tmp_path):
    biased = train_config(1, time_distribution="beta:1.5")
    with pytest.raises(InvalidInputError, match="distill: time_distribution 'beta:1.5' is a teacher's setting"):
        distill(tmp_path / "teacher", demonstrations, tmp_path / "student", biased, progress=False)
    with pytest.raises(InvalidInputError, match="a student's training: time_distribution 'beta:1.5'"):
        StudentRun("teacher", Source(demonstrations), tmp_path / "student", biased, DistillSettings())
    with pytest.raises(InvalidInputError, match="a LeRobot teacher trains on its own type's flow-matching times"):
        family_of("smolvla").check_teacher_training("smolvla", biased)
    family_of("minivla").check_teacher_training("minivla", biased)  # a built-in teacher takes it
    assert not (tmp_path / "student").exists()


def test_snapflow_train_records_the_distribution_its_flag_names(demonstrations, tmp_path):
    """The command as a user runs it, from another folder: the flag's value, written one way, in the checkpoint."""
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    command = [sys.executable, "-m", "snapflow.cli", "train", "--data", str(demonstrations), "--output", "run"]
    command += ["--steps", "1", "--batch-size", "2", "--no-progress", "--time-distribution", "shift:4.0"]
    result = subprocess.run(command, cwd=elsewhere, capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stderr
    assert _checkpoint(elsewhere / "run")["time_distribution"] == "shift:4"
    assert (
        json.loads((elsewhere / "run" / "history.json").read_text())["train_config"]["time_distribution"] == "shift:4"
    )
