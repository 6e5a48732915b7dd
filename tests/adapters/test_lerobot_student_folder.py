"""A SnapFlow student's folder asked for under its teacher's LeRobot type is refused by name wherever snapflow loads
it, never loaded as the plain teacher with phi_s dropped; under its own type, or as the teacher it is not, it loads."""

from __future__ import annotations

import json
import shutil
from dataclasses import fields
from pathlib import Path

import pytest

pytest.importorskip("lerobot", reason="LeRobot is installed by the README's test command; this environment lacks it")

from snapflow.adapters.lerobot import load_pretrained_policy, save_distilled, wrap_policy  # noqa: E402
from snapflow.adapters.lerobot.checkpoint import SNAPFLOW_MARKER, save_teacher  # noqa: E402
from snapflow.adapters.lerobot.plugin import SnapFlowSampling  # noqa: E402
from snapflow.adapters.lerobot.student_folder import (  # noqa: E402
    StudentAsTeacherError,
    distilled_from,
    refuse_student_as_teacher,
)
from snapflow.policies.loaded import CheckpointError  # noqa: E402
from snapflow.sources import open_policy  # noqa: E402
from tests.lerobot_tiny import build_tiny_smolvla, cache_as_hub_repo, randomise_target_time  # noqa: E402


@pytest.fixture
def student(vlm_directory, tmp_path) -> Path:
    return save_distilled(randomise_target_time(wrap_policy(build_tiny_smolvla(vlm_directory))), tmp_path / "student")


def _retyped_as_teacher(student: Path, folder: Path, marker: bool) -> Path:
    """The student with its config typed as the plain SmolVLA (what a user does so that a LeRobot without snapflow's
    plugin reads it; an export older than the student types looks the same), with or without snapflow's marker."""
    shutil.copytree(student, folder)
    config = json.loads((folder / "config.json").read_text())
    own = {definition.name for definition in fields(SnapFlowSampling)}
    for name in [name for name in config if name in own]:
        del config[name]  # the student's own fields: the teacher's config class reads none of them
    (folder / "config.json").write_text(json.dumps({**config, "type": "smolvla"}))
    if not marker:
        (folder / SNAPFLOW_MARKER).unlink()
    return folder


def test_a_student_is_refused_under_its_teachers_type_and_accepted_under_its_own(student, vlm_directory, tmp_path):
    assert distilled_from(student) == "smolvla"
    with pytest.raises(StudentAsTeacherError, match="distilled from smolvla: loaded as 'smolvla'.*'snapflow_smolvla'"):
        refuse_student_as_teacher(student, "smolvla")
    assert issubclass(StudentAsTeacherError, CheckpointError)  # one line at the command line, as other load errors
    refuse_student_as_teacher(student, "snapflow_smolvla")

    teacher = save_teacher(wrap_policy(build_tiny_smolvla(vlm_directory)), tmp_path / "teacher", 0.0)
    assert distilled_from(teacher) is None
    refuse_student_as_teacher(teacher, "smolvla")
    (tmp_path / "empty").mkdir()
    assert distilled_from(tmp_path / "empty") is None  # not a LeRobot policy: its loader says so

    cache_as_hub_repo(student, "acme/student-folder")  # a hub id reads the same files, from the cache
    with pytest.raises(StudentAsTeacherError, match="^acme/student-folder holds a SnapFlow student"):
        refuse_student_as_teacher("acme/student-folder", "smolvla")


def test_a_student_typed_as_its_teacher_is_refused_by_snapflows_loaders_unless_its_marker_says_distilled(
    student, tmp_path
):
    bare = _retyped_as_teacher(student, tmp_path / "bare", marker=False)
    assert distilled_from(bare) == "smolvla"  # phi_s in its weights says so
    with pytest.raises(StudentAsTeacherError, match="bare holds a SnapFlow student distilled from smolvla"):
        load_pretrained_policy(str(bare))
    with pytest.raises(StudentAsTeacherError):  # what eval, bench, export and distill --policy open
        open_policy(bare)

    # snapflow's marker says distilled: the student is rebuilt as its student type, phi_s loaded strictly
    marked = open_policy(_retyped_as_teacher(student, tmp_path / "marked", marker=True))
    assert marked.distilled and marked.policy.target_time_embedding.linear_out.weight.abs().sum() > 0
