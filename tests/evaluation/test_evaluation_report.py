"""The evaluation pipeline's report and its files on the scripted benchmark: success, offline error and latency, rows
left out, and an interrupted run resumed from its episode log."""

import json

import numpy as np
import pytest

from snapflow.data.chunks import ChunkData
from snapflow.data.demonstrations import Demonstrations
from snapflow.envs.base import Observation
from snapflow.evaluation.closed_loop import ClosedLoopEvaluator
from snapflow.evaluation.episode_log import EpisodeLog
from snapflow.evaluation.offline import offline_metrics
from snapflow.evaluation.pipeline import evaluate
from snapflow.evaluation.report import markdown_report, write_report
from snapflow.evaluation.results import (
    EvaluationReport,
    EvaluationRow,
)
from snapflow.flow.modes import NAIVE_1, SNAPFLOW_1, TEACHER_10, SamplingMode
from snapflow.reporting.files import recorded_path
from tests.evaluation.figures import CYCLE, assert_figure
from tests.training.fixtures import SYNTHETIC_TASKS


def test_evaluate_reports_success_offline_error_and_latency_and_writes_every_file(scripted, runs, tmp_path):
    data, teacher, student = runs
    labelled = [
        ("teacher 10-NFE", teacher, TEACHER_10),
        ("naive 1-NFE", teacher, NAIVE_1),
        ("SnapFlow 1-NFE", student, SNAPFLOW_1),
    ]
    report = evaluate(
        labelled, scripted, list(SYNTHETIC_TASKS), 2, n_act=4, data=data, offline_samples=20, progress=False
    )
    assert isinstance(report, EvaluationReport) and list(report.rows) == [label for label, _, _ in labelled]
    assert (report.env, report.tasks, report.episodes_per_task, report.n_act) == (
        "scripted",
        list(SYNTHETIC_TASKS),
        2,
        4,
    )
    demonstrations = Demonstrations.load(data)
    for label, loaded, mode in labelled:
        row = report.rows[label]
        assert (row.policy, row.mode, row.nfe) == (
            recorded_path(loaded.path),  # never an absolute path of this machine
            mode.name,
            mode.num_steps,
        ) and row.closed_loop_s > 0
        assert all(row.success[task].episodes == 2 for task in SYNTHETIC_TASKS) and row.success["mean"].episodes == 4
        assert row.success["mean"].successes == sum(row.success[task].successes for task in SYNTHETIC_TASKS)
        # offline: the checkpoint's own held-out episodes, every mode on the same draws
        _, val_episodes = demonstrations.split(loaded.val_fraction)
        expected = offline_metrics(
            loaded.policy, ChunkData(demonstrations, val_episodes, loaded.processor), mode, 20, 0
        )
        assert row.offline == expected and row.offline.samples == 20
        latency = report.latency[label]
        assert latency.nfe == mode.num_steps and latency.prefix is not None and latency.prefix.repeats == 50
    assert report.latency["teacher 10-NFE"].end_to_end_speedup == 1.0
    one_step, reference = report.latency["SnapFlow 1-NFE"], report.latency["teacher 10-NFE"]
    assert one_step.denoising_speedup == reference.denoising.median_ms / one_step.denoising.median_ms

    write_report(report, tmp_path)
    written = json.loads((tmp_path / "report.json").read_text())
    assert written == json.loads(json.dumps(report.to_dict())) and written["machine"] == report.machine
    assert written["rows"]["SnapFlow 1-NFE"]["success"]["mean"] == {
        "successes": report.rows["SnapFlow 1-NFE"].success["mean"].successes,
        "episodes": 4,
        "success_rate": report.rows["SnapFlow 1-NFE"].success["mean"].success_rate,
    }
    assert {label: EvaluationRow.from_dict(row) for label, row in written["rows"].items()} == report.rows
    assert (
        written["latency"]["SnapFlow 1-NFE"]["nfe"] == 1
        and written["latency"]["naive 1-NFE"]["prefix"]["repeats"] == 50
    )
    markdown = (tmp_path / "report.md").read_text()
    assert markdown == markdown_report(report) and markdown.startswith("# SnapFlow on Scripted test benchmark")
    mean = report.rows["SnapFlow 1-NFE"].success["mean"]
    assert "| **mean** |" in markdown and f"{100 * mean.success_rate:.1f}% ({mean.successes}/4)" in markdown
    assert "## Offline action error (20 held-out demonstration chunks, normalised actions)" in markdown
    assert f"| SnapFlow 1-NFE | {report.rows['SnapFlow 1-NFE'].offline.mse:.4f} |" in markdown
    assert f"| SnapFlow 1-NFE | 1 | {one_step.prefix.median_ms:.2f} | {one_step.denoising.median_ms:.2f} |" in markdown
    # three tasks' groups (two tasks and the mean) of three bars, and the legend, whatever the success
    assert_figure(tmp_path / "success.png", (6, 4), {CYCLE[0]: 0.0003, CYCLE[1]: 0.0003, CYCLE[2]: 0.0003})
    assert_figure(tmp_path / "latency.png", (6, 3.5), {CYCLE[0]: 0.0003, CYCLE[1]: 0.005})


def test_a_report_without_data_or_timing_leaves_those_sections_out(scripted, runs, tmp_path):
    _, teacher, _ = runs
    report = evaluate([("naive", teacher, NAIVE_1)], scripted, ["reach-v3"], 1, progress=False, timing=False)
    assert report.rows["naive"].offline is None and report.latency == {}
    write_report(report, tmp_path)
    written = json.loads((tmp_path / "report.json").read_text())
    assert "offline" not in written["rows"]["naive"] and "latency" not in written
    assert (
        "Offline action error" not in (tmp_path / "report.md").read_text() and not (tmp_path / "latency.png").exists()
    )
    assert (tmp_path / "success.png").is_file()
    assert SamplingMode.parse(written["rows"]["naive"]["mode"]) == NAIVE_1


def test_an_interrupted_run_resumes_from_its_episode_log_as_if_never_interrupted(scripted, runs, tmp_path):
    _, teacher, _ = runs
    policy, processor = teacher.policy, teacher.processor
    # two tasks, one environment each: three waves, variation v of both tasks in wave v
    evaluator = ClosedLoopEvaluator(scripted, list(SYNTHETIC_TASKS), 3, image_size=None, max_envs=2)
    whole: dict[int, list[np.ndarray]] = {}
    uninterrupted = evaluator.run(
        policy, processor, TEACHER_10, 4, 3, False, record=lambda slot, _, a: whole.setdefault(slot, []).append(a)
    )

    def stop_in_wave_two(slot: int, observation: Observation, action: np.ndarray) -> None:
        if slot % 3 == 1:  # slots are task-major: variation 1 of either task
            raise KeyboardInterrupt

    identity = {"label": "teacher", "seed": 3}
    path = tmp_path / "episodes" / "00-teacher.jsonl"
    with pytest.raises(KeyboardInterrupt):
        evaluator.run(policy, processor, TEACHER_10, 4, 3, False, stop_in_wave_two, EpisodeLog(path, identity, False))
    log = EpisodeLog(path, identity, resume=True)
    assert len(log.finished) == 1 and log.finished[0].episodes == [uninterrupted[0], uninterrupted[3]]
    assert log.finished[0].seconds > 0

    rerun: dict[int, list[np.ndarray]] = {}
    resumed = evaluator.run(
        policy, processor, TEACHER_10, 4, 3, False, lambda slot, _, a: rerun.setdefault(slot, []).append(a), log
    )
    evaluator.close()
    assert resumed == uninterrupted
    assert sorted(rerun) == [1, 2, 4, 5], "wave one is read back, not run again"
    for slot, actions in rerun.items():  # the same noise as the uninterrupted run's: the generator's state restored
        assert np.array_equal(np.stack(actions), np.stack(whole[slot]))
    assert len(path.read_text().splitlines()) == 4, "the identity and three waves"

    with pytest.raises(ValueError, match="another evaluation \\(it differs in seed\\)"):
        EpisodeLog(path, {**identity, "seed": 4}, resume=True)
    with path.open("a") as file:  # a line cut short by an interruption is dropped on reading, and from the file
        file.write('{"episodes": [{"task"')
    assert [wave.episodes for wave in EpisodeLog(path, identity, resume=True).finished] == [
        [uninterrupted[v], uninterrupted[3 + v]] for v in range(3)
    ]
    assert len(path.read_text().splitlines()) == 4
    lines = path.read_text().splitlines()
    path.write_text("\n".join([lines[0], "garbage", *lines[2:]]) + "\n")
    with pytest.raises(ValueError, match="corrupt at line 2"):
        EpisodeLog(path, identity, resume=True)
    assert EpisodeLog(path, identity, resume=False).finished == [] and len(path.read_text().splitlines()) == 1


def test_evaluate_with_episode_logs_resumes_a_finished_row_without_running_an_episode(scripted, runs, tmp_path):
    _, teacher, student = runs
    labelled = [("teacher 10-NFE", teacher, TEACHER_10), ("SnapFlow 1-NFE", student, SNAPFLOW_1)]

    def logged_evaluation(labelled_runs, episodes_per_task: int, resume: bool) -> EvaluationReport:
        tasks = list(SYNTHETIC_TASKS)
        return evaluate(
            labelled_runs,
            scripted,
            tasks,
            episodes_per_task,
            progress=False,
            timing=False,
            episode_logs=tmp_path,
            resume=resume,
        )

    first = logged_evaluation(labelled, 2, resume=False)
    assert sorted(path.name for path in tmp_path.iterdir()) == ["00-teacher_10-NFE.jsonl", "01-SnapFlow_1-NFE.jsonl"]
    environments = len(scripted.envs)
    again = logged_evaluation(labelled, 2, resume=True)
    assert len(scripted.envs) == environments, "every wave read back: no environment made"
    for (label, _, _), path in zip(labelled, sorted(tmp_path.iterdir()), strict=True):
        assert again.rows[label].success == first.rows[label].success
        # the time a row took counts its logged waves' time, not only that of reading them back
        logged = sum(json.loads(line)["seconds"] for line in path.read_text().splitlines()[1:])
        assert again.rows[label].closed_loop_s >= logged > 0
    with pytest.raises(ValueError, match="differs in envs_per_task, episodes_per_task"):
        logged_evaluation(labelled, 1, resume=True)
    # the same label, other weights (the policies' folders share their last part, all a path outside the working
    # directory is recorded by: the weights tell them apart)
    with pytest.raises(ValueError, match="differs in weights"):
        logged_evaluation([("teacher 10-NFE", student, TEACHER_10)], 2, resume=True)
