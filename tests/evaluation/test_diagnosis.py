"""`snapflow diagnose` on real Meta-World episodes: the distance to the scripted expert at every visited state, the
failing phase, and every row's chunks at the failed moments against the nearest demonstration, checked by hand."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

from snapflow.cli import main
from snapflow.data.demonstrations import Demonstrations
from snapflow.envs.factory import make_benchmark
from snapflow.evaluation.diagnosis import PHASE_STEPS, diagnose_task
from snapflow.flow.modes import SamplingMode
from snapflow.policies.checkpoint import load_policy
from snapflow.training.recipes import DistillSettings
from snapflow.training.stages import distill, train_teacher
from tests.training.fixtures import TASK, TINY, collected, train_config

EPISODES = 2


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """A barely trained teacher and student: they fail the task, so there is a failing phase to find."""
    data = collected(tmp_path_factory, episodes_per_task=3)
    root = tmp_path_factory.mktemp("runs")
    train_teacher(data, root / "teacher", TINY, train_config(3), progress=False)
    distill(root / "teacher", data, root / "student", train_config(3), DistillSettings(), progress=False)
    return data, root / "teacher", root / "student"


def test_the_diagnosis_scores_episodes_against_the_expert_and_compares_chunks(runs, tmp_path):
    data, teacher_path, student_path = runs
    teacher, student = load_policy(teacher_path), load_policy(student_path)
    rows = [
        ("teacher 10-NFE", teacher, SamplingMode.parse("teacher-10")),
        ("SnapFlow 1-NFE", student, SamplingMode.parse("snapflow-1")),
    ]
    demonstrations = Demonstrations.load(data)
    diagnosis = diagnose_task(rows, make_benchmark("metaworld"), TASK, EPISODES, demonstrations, 4, progress=False)
    assert [row.label for row in diagnosis.rows] == ["teacher 10-NFE", "SnapFlow 1-NFE"]
    student_row = diagnosis.rows[-1]
    assert student_row.successes == 0 and student_row.episodes == EPISODES, "three training steps solve nothing"
    # every failed episode runs to Meta-World's step limit, so every phase holds a failed-episode mean
    assert len(student_row.deviation_failed) == -(-500 // PHASE_STEPS)
    assert all(value is not None for value in student_row.deviation_failed)
    assert all(value is None for value in student_row.deviation_succeeded)
    teacher_all = diagnosis.rows[0].deviation_all
    excess = [value - teacher_all[phase] for phase, value in enumerate(student_row.deviation_failed)]
    assert diagnosis.failing_phase == int(np.argmax(excess))
    assert len(diagnosis.comparisons) == EPISODES  # one moment per failed episode, at most `states`
    for comparison in diagnosis.comparisons:
        assert diagnosis.failing_phase * PHASE_STEPS <= comparison.step < (diagnosis.failing_phase + 1) * PHASE_STEPS
        assert comparison.step % 4 == 0, "a moment where the student sampled a chunk (n_act 4)"
        assert all(-1 <= value <= 1 for value in comparison.expert_action), "the action the environment applies"
        for label, chunks in comparison.chunks.items():
            chunks = np.asarray(chunks)
            assert chunks.shape == (8, TINY.chunk_length, 4)
            reference = np.asarray(comparison.demonstration_chunk)
            assert comparison.error_to_demonstration[label] == pytest.approx(((chunks - reference) ** 2).mean())
            assert comparison.spread[label] == pytest.approx(chunks.std(0).mean())
            to_expert = np.linalg.norm(chunks[:, 0] - np.asarray(comparison.expert_action), axis=1).mean()
            assert comparison.first_action_to_expert[label] == pytest.approx(to_expert, rel=1e-6)
    # the nearest demonstration state of the task, by brute force, and the chunk that follows it in its episode
    for comparison in diagnosis.comparisons:
        distances = [
            (float(np.linalg.norm(demonstrations.states[row] - np.asarray(comparison.state))), row, episode)
            for episode, e in enumerate(demonstrations.episodes)
            if e.task == TASK
            for row in range(e.start, e.start + e.length)
        ]
        distance, row, episode = min(distances)
        assert comparison.demonstration_distance == pytest.approx(distance, rel=1e-5)
        end = demonstrations.episodes[episode].start + demonstrations.episodes[episode].length
        following = [demonstrations.actions[min(row + k, end - 1)] for k in range(TINY.chunk_length)]
        assert np.allclose(comparison.demonstration_chunk, following)


def test_the_command_writes_the_report_and_its_figures(runs, tmp_path):
    data, teacher, student = runs
    output = tmp_path / "diagnosis"
    code = main(
        [
            "diagnose",
            "--teacher",
            str(teacher),
            "--student",
            str(student),
            "--task",
            TASK,
            "--episodes",
            "1",
            "--no-progress",
            "--output",
            str(output),
        ]
    )
    assert code == 0
    report = json.loads((output / "diagnosis.json").read_text())
    assert [row["label"] for row in report["rows"]] == ["teacher 10-NFE", "naive 1-NFE", "SnapFlow 1-NFE"]
    assert (output / "phases.png").stat().st_size > 0 and (output / "chunks-0.png").stat().st_size > 0
    assert "Failing phase of SnapFlow 1-NFE" in (output / "diagnosis.md").read_text()


def test_a_camera_policy_is_compared_where_its_frames_were_rendered(tmp_path_factory, tmp_path):
    """The evaluator renders a frame only where a chunk is sampled (every n_act-th step), so the failed moments whose
    chunks are compared are those: a camera policy's diagnosis reads a frame at each."""
    task = "pick-place-v3"  # out of reach of three training steps, so there is a failed moment to compare at
    data = collected(tmp_path_factory, (task,), episodes_per_task=2, image_size=32)
    config = replace(TINY, use_image=True, image_size=32, patch_size=16)
    train_teacher(data, tmp_path / "teacher", config, train_config(3), progress=False)
    distill(tmp_path / "teacher", data, tmp_path / "student", train_config(3), DistillSettings(), progress=False)
    rows = [
        ("teacher 10-NFE", load_policy(tmp_path / "teacher"), SamplingMode.parse("teacher-10")),
        ("SnapFlow 1-NFE", load_policy(tmp_path / "student"), SamplingMode.parse("snapflow-1")),
    ]
    diagnosis = diagnose_task(rows, make_benchmark("metaworld"), task, 1, Demonstrations.load(data), 4, progress=False)
    assert diagnosis.rows[-1].successes == 0 and len(diagnosis.comparisons) == 1
    (comparison,) = diagnosis.comparisons
    assert comparison.step % 4 == 0
    assert np.asarray(comparison.chunks["SnapFlow 1-NFE"]).shape == (8, TINY.chunk_length, 4)
