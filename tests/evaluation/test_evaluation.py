"""Evaluation without a simulator: closed-loop re-planning, offline metrics, the pipeline's report and its files, on a
scripted benchmark registered for the test (the same code runs Meta-World in tests/evaluation/test_pipeline.py)."""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Sequence

import numpy as np
import pytest
import torch

from snapflow.data.chunks import ChunkData
from snapflow.data.demonstrations import Demonstrations
from snapflow.envs import factory
from snapflow.envs.base import Benchmark, Environment, Observation
from snapflow.errors import InvalidInputError
from snapflow.evaluation.closed_loop import ClosedLoopEvaluator
from snapflow.evaluation.episode_log import EpisodeLog
from snapflow.evaluation.offline import offline_metrics
from snapflow.evaluation.pipeline import evaluate, runs_evaluator
from snapflow.evaluation.report import markdown_report, write_report
from snapflow.evaluation.results import (
    EpisodeResult,
    EvaluationReport,
    EvaluationRow,
    OfflineMetrics,
    SuccessCount,
    success_by_task,
)
from snapflow.flow.modes import NAIVE_1, SNAPFLOW_1, TEACHER_10, SamplingMode
from snapflow.flow.solver import sample_actions
from snapflow.policies.checkpoint import load_policy
from snapflow.policies.factory import default_config
from snapflow.policies.mlp.processor import MLPProcessor
from snapflow.reporting.files import recorded_path
from snapflow.reporting.statistics import wilson_interval
from snapflow.training.recipes import DistillSettings
from snapflow.training.stages import distill, train_teacher
from tests.evaluation.figures import CYCLE, assert_figure
from tests.training.fixtures import ACTION_DIM, STATE_DIM, SYNTHETIC_TASKS, synthetic_demonstrations, train_config

EPISODE_STEPS = 6


class ScriptedEnv(Environment):
    """A fixed state per variation; every action is recorded; an episode lasts ``EPISODE_STEPS`` steps and succeeds
    when the first action dimension summed over it is positive."""

    def __init__(self, task: str) -> None:
        self.task, self.instruction, self.steps, self.closed = task, SYNTHETIC_TASKS[task], 0, False
        self.actions: list[np.ndarray] = []
        self.state = np.zeros(STATE_DIM, np.float32)

    def reset(self, variation: int, render: bool = True) -> Observation:
        self.state = np.random.default_rng([variation, len(self.task)]).standard_normal(STATE_DIM).astype(np.float32)
        self.steps, self.actions = 0, []
        return Observation(self.state, self.instruction)

    def step(self, action: np.ndarray, render: bool = False) -> tuple[Observation, bool, bool]:
        self.steps += 1
        self.actions.append(np.asarray(action))
        done = self.steps == EPISODE_STEPS
        return Observation(self.state, self.instruction), done and float(np.sum([a[0] for a in self.actions])) > 0, done

    def close(self) -> None:
        self.closed = True


class ScriptedBenchmark(Benchmark):
    name, title = "scripted", "Scripted test benchmark"
    state_dim, action_dim, max_episode_steps = STATE_DIM, ACTION_DIM, EPISODE_STEPS
    camera, extra_cameras = "image", ("wrist",)

    def __init__(self) -> None:
        self.envs: list[ScriptedEnv] = []
        self.rendered_cameras: list[tuple[str, ...] | None] = []  # each environment's extra cameras, as asked for

    @property
    def tasks(self) -> tuple[str, ...]:
        return tuple(SYNTHETIC_TASKS)

    def instruction(self, task: str) -> str:
        return SYNTHETIC_TASKS[task]

    def num_variations(self, split: str) -> int:
        return 3

    def make_env(
        self, task: str, split: str, image_size: int | None = None, extra_cameras: Sequence[str] | None = None
    ) -> ScriptedEnv:
        self.rendered_cameras.append(None if extra_cameras is None else tuple(extra_cameras))
        self.envs.append(ScriptedEnv(task))
        return self.envs[-1]

    def make_expert(self, task: str):
        raise NotImplementedError


@pytest.fixture
def scripted(monkeypatch) -> ScriptedBenchmark:
    monkeypatch.setitem(factory.BENCHMARKS, ScriptedBenchmark.name, ScriptedBenchmark)  # reports name their benchmark
    return ScriptedBenchmark()


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """Demonstrations, an MLP teacher and its SnapFlow student, trained a few steps."""
    root = tmp_path_factory.mktemp("runs")
    data = synthetic_demonstrations(episodes_per_task=5).save(root / "demos")
    config = default_config(
        "mlp",
        STATE_DIM,
        ACTION_DIM,
        list(SYNTHETIC_TASKS.values()),
        chunk_length=4,
        hidden_dim=32,
        time_embedding_dim=16,
    )
    train_teacher(data, root / "teacher", config, train_config(3), val_fraction=0.2, progress=False)
    distill(root / "teacher", data, root / "student", train_config(3), DistillSettings(), progress=False)
    return data, load_policy(root / "teacher"), load_policy(root / "student")


def test_success_is_counted_per_task_and_averaged_over_tasks():
    results = [EpisodeResult("a", 0, True, 5), EpisodeResult("a", 1, False, 9), EpisodeResult("b", 0, True, 3)]
    table = success_by_task(results)
    assert table == {"a": SuccessCount(1, 2, 0.5), "b": SuccessCount(1, 1, 1.0), "mean": SuccessCount(2, 3, 0.75)}


def test_a_report_gives_each_rows_wilson_interval_and_its_paired_difference_from_the_first():
    def row(counts: list[int]) -> EvaluationRow:
        results = [
            EpisodeResult(task, episode, episode < successes, 10)
            for task, successes in zip(("a", "b", "c"), counts, strict=True)
            for episode in range(20)
        ]
        return EvaluationRow("p", "teacher-10", 10, success_by_task(results), 1.0)

    report = EvaluationReport(
        "metaworld", ["a", "b", "c"], 20, 4, {"teacher": row([10, 15, 20]), "student": row([11, 16, 20])}
    )
    intervals = report.intervals()
    assert set(intervals["teacher"]) == {"success", "low", "high"}, "the first row is the reference"
    low, high = wilson_interval(45, 60)
    assert intervals["teacher"]["success"] == pytest.approx(75.0)
    assert (intervals["teacher"]["low"], intervals["teacher"]["high"]) == pytest.approx((100 * low, 100 * high))
    student = intervals["student"]
    assert student["difference"] == pytest.approx((5 + 5 + 0) / 3)  # per task: +1/20, +1/20, 0
    assert student["difference_low"] <= student["difference"] <= student["difference_high"]
    # 5 points above the teacher on every task: the paired interval is exactly [5, 5]
    constant = EvaluationReport(
        "metaworld", ["a", "b", "c"], 20, 4, {"teacher": row([10, 15, 18]), "student": row([11, 16, 19])}
    )
    shifted = constant.intervals()["student"]
    assert [shifted[key] for key in ("difference", "difference_low", "difference_high")] == pytest.approx([5.0] * 3)
    assert report.to_dict()["intervals"] == intervals
    assert "points from teacher [95% paired bootstrap]" in markdown_report(report)


def test_closed_loop_replans_every_n_act_actions_in_one_batch_and_scores_each_episode(scripted, runs):
    _, teacher, _ = runs
    policy, processor = teacher.policy, teacher.processor
    encodes = []
    encode = policy.encode
    policy.encode = lambda observation: encodes.append(len(observation)) or encode(observation)
    try:
        evaluator = ClosedLoopEvaluator(scripted, list(SYNTHETIC_TASKS), 2, image_size=None)
        results = evaluator.run(policy, processor, TEACHER_10, n_act=4, seed=3, progress=False)
        evaluator.close()
    finally:
        del policy.encode  # the module's shared policy gets its own method back
    envs = scripted.envs
    assert [(r.task, r.variation, r.steps) for r in results] == [
        (task, v, EPISODE_STEPS) for task in SYNTHETIC_TASKS for v in range(2)
    ]
    assert all(env.closed for env in envs)
    assert encodes == [4, 4], "every environment re-plans at steps 0 and 4, all in one batch"
    # the executed actions are the policy's chunks, unnormalised, drawn from the seeded noise in re-planning order
    generator = torch.Generator().manual_seed(3)
    states = np.stack([env.state for env in envs])
    observation = processor.observation(states, [env.instruction for env in envs])
    chunks = []
    for _ in range(2):
        noise = torch.randn(4, processor.chunk_length, processor.action_dim, generator=generator)
        chunks.append(processor.unnormalize_actions(sample_actions(policy, observation, noise, TEACHER_10)).numpy())
    for row, (env, result) in enumerate(zip(envs, results, strict=True)):
        expected = np.concatenate([chunks[0][row, :4], chunks[1][row, :2]])
        assert np.allclose(np.stack(env.actions), expected, atol=1e-6)
        assert result.success == (expected[:, 0].sum() > 0)
    with pytest.raises(ValueError, match=r"n_act must be in \[1, 4\]"):
        ClosedLoopEvaluator(scripted, ["reach-v3"], 1).run(policy, processor, NAIVE_1, n_act=5, progress=False)
    with pytest.raises(ValueError, match=r"episodes per task must be in \[1, 3\]"):
        ClosedLoopEvaluator(scripted, ["reach-v3"], 4)
    with pytest.raises(ValueError, match=r"unknown scripted task\(s\) \['fly-v3'\]"):
        ClosedLoopEvaluator(scripted, ["fly-v3"], 1)


def test_environments_render_only_the_cameras_the_evaluated_policies_read(scripted, runs):
    """A benchmark's extra camera is asked of its environments only when a policy being evaluated reads it: frames
    nobody reads are not rendered (LIBERO's wrist camera for a policy of the agentview alone); a policy reading a
    camera its evaluator does not render, or a camera the benchmark lacks, is refused by name."""
    _, teacher, student = runs

    class WristReader(MLPProcessor):  # the teacher's processor, as if its policy also read the wrist camera
        extra_cameras = ("wrist",)

    wrist = WristReader(teacher.processor.config, teacher.processor.stats, teacher.processor.instructions)
    runs_evaluator([("teacher", teacher, TEACHER_10)], scripted, ["reach-v3"], 1).run(
        teacher.policy, teacher.processor, TEACHER_10, n_act=4, progress=False
    )
    assert scripted.rendered_cameras == [()], "the MLP teacher reads no camera: none is rendered"
    both = [("teacher", teacher, TEACHER_10), ("student", dataclasses.replace(student, processor=wrist), SNAPFLOW_1)]
    assert runs_evaluator(both, scripted, ["reach-v3"], 1).extra_cameras == ("wrist",), "one of the runs reads it"
    with pytest.raises(ValueError, match=r"reads camera\(s\) \['wrist'\] that this evaluator does not render"):
        ClosedLoopEvaluator(scripted, ["reach-v3"], 1).run(teacher.policy, wrist, TEACHER_10, n_act=4, progress=False)
    with pytest.raises(ValueError, match=r"scripted has no camera\(s\) \['side'\]: .* renders \['wrist'\]"):
        ClosedLoopEvaluator(scripted, ["reach-v3"], 1, extra_cameras=["side"])


def test_more_episodes_than_max_envs_run_in_waves_on_the_same_environments_and_one_noise_stream(scripted, runs):
    _, teacher, _ = runs
    policy, processor = teacher.policy, teacher.processor
    actions: dict[int, list[np.ndarray]] = {}
    evaluator = ClosedLoopEvaluator(scripted, list(SYNTHETIC_TASKS), 2, image_size=None, max_envs=3)
    run = evaluator.run(
        policy,
        processor,
        TEACHER_10,
        4,
        3,
        False,
        record=lambda slot, _, action: actions.setdefault(slot, []).append(action),
    )
    again = evaluator.run(policy, processor, TEACHER_10, n_act=4, seed=3, progress=False)
    evaluator.close()
    assert [(r.task, r.variation) for r in run] == [(task, v) for task in SYNTHETIC_TASKS for v in range(2)]
    assert run == again
    assert len(scripted.envs) == 2, "3 // 2 tasks: one environment per task, reset for each variation and run"
    assert all(env.closed for env in scripted.envs)
    # by hand: wave 1 is variation 0 of both tasks (slots 0 and 2), re-planning at steps 0 and 4, then wave 2 is
    # variation 1 (slots 1 and 3), drawing from the same generator
    generator = torch.Generator().manual_seed(3)
    expected = {}
    for variation in range(2):
        wave = [ScriptedEnv(task) for task in SYNTHETIC_TASKS]
        observations = [env.reset(variation) for env in wave]
        batch = processor.observation(np.stack([o.state for o in observations]), [o.instruction for o in observations])
        chunks = []
        for _ in range(2):
            noise = torch.randn(len(wave), processor.chunk_length, processor.action_dim, generator=generator)
            chunks.append(processor.unnormalize_actions(sample_actions(policy, batch, noise, TEACHER_10)).numpy())
        for row in range(len(wave)):
            expected[2 * row + variation] = np.concatenate([chunks[0][row, :4], chunks[1][row, :2]])
    for slot in range(4):
        assert np.allclose(np.stack(actions[slot]), expected[slot], atol=1e-6)
    with pytest.raises(ValueError, match="max_envs must be at least 1"):
        ClosedLoopEvaluator(scripted, ["reach-v3"], 1, max_envs=0)


def test_episodes_start_from_the_first_variation_asked_for_and_past_the_last_are_refused(scripted, runs):
    _, teacher, _ = runs
    available = scripted.num_variations("eval")
    evaluator = ClosedLoopEvaluator(scripted, list(SYNTHETIC_TASKS), 2, first_variation=available - 2)
    run = evaluator.run(teacher.policy, teacher.processor, TEACHER_10, n_act=4, seed=3, progress=False)
    evaluator.close()
    # the same two slots a task, on the last two variations instead of the first two
    assert [(r.task, r.variation) for r in run] == [
        (task, variation) for task in SYNTHETIC_TASKS for variation in (available - 2, available - 1)
    ]
    with pytest.raises(InvalidInputError, match=rf"must be in \[1, 1\] .* variations from variation {available - 1}\)"):
        ClosedLoopEvaluator(scripted, ["reach-v3"], 2, first_variation=available - 1)


def test_episodes_cut_at_max_episode_steps_end_there_and_score_what_they_reached(scripted, runs):
    _, teacher, _ = runs
    evaluator = ClosedLoopEvaluator(scripted, list(SYNTHETIC_TASKS), 2, max_episode_steps=3)
    run = evaluator.run(teacher.policy, teacher.processor, TEACHER_10, n_act=4, seed=3, progress=False)
    evaluator.close()
    assert [r.steps for r in run] == [3] * len(run) and all(len(env.actions) == 3 for env in scripted.envs)
    assert not any(r.success for r in run), "the scripted episodes succeed only at their own last step"
    with pytest.raises(InvalidInputError, match="max_episode_steps must be at least 1, got 0"):
        ClosedLoopEvaluator(scripted, ["reach-v3"], 1, max_episode_steps=0)


def test_offline_metrics_summarise_the_per_chunk_errors_of_fixed_draws(runs):
    data, teacher, _ = runs
    demonstrations = Demonstrations.load(data)
    _, val_episodes = demonstrations.split(teacher.val_fraction)
    chunks = ChunkData(demonstrations, val_episodes, teacher.processor)
    metrics = offline_metrics(teacher.policy, chunks, TEACHER_10, max_samples=15, seed=4)
    assert isinstance(metrics, OfflineMetrics) and metrics.samples == 15 < len(chunks)
    # by hand: the seed fixes which chunks and which noise
    generator = torch.Generator().manual_seed(4)
    indices = torch.randperm(len(chunks), generator=generator)[:15]
    noise = torch.randn((15, *chunks.actions.shape[1:]), generator=generator)
    observation, target = chunks.batch(indices)
    prediction = sample_actions(teacher.policy, observation, noise, TEACHER_10)
    errors = (prediction - target).pow(2).flatten(1).mean(1).double()
    cosine = torch.nn.functional.cosine_similarity(prediction.flatten(1), target.flatten(1), dim=1).double().mean()
    assert metrics.mse == pytest.approx(errors.mean().item()) and metrics.mse_median == pytest.approx(
        errors.median().item()
    )
    assert metrics.mse_std == pytest.approx(errors.std().item()) and metrics.cosine == pytest.approx(cosine.item())
    assert metrics.mse_p95 == pytest.approx(torch.quantile(errors, 0.95).item()) and metrics.mse_p90 <= metrics.mse_p95
    assert offline_metrics(teacher.policy, chunks, TEACHER_10, max_samples=15, seed=4) == metrics
    assert offline_metrics(teacher.policy, chunks, NAIVE_1, max_samples=15, seed=4) != metrics


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
    with pytest.raises(ValueError, match="differs in policy, weights"):  # the same label, other weights
        logged_evaluation([("teacher 10-NFE", student, TEACHER_10)], 2, resume=True)
