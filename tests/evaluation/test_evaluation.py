"""Evaluation without a simulator: closed-loop re-planning, offline metrics, the pipeline's report and its files, on a
scripted benchmark registered for the test (the same code runs Meta-World in tests/evaluation/test_pipeline.py)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from snapflow.data.chunks import ChunkData
from snapflow.data.demonstrations import Demonstrations
from snapflow.errors import InvalidInputError
from snapflow.evaluation.closed_loop import ClosedLoopEvaluator
from snapflow.evaluation.episode_log import EpisodeLog
from snapflow.evaluation.offline import offline_metrics
from snapflow.evaluation.path_modes import path_modes_by_task
from snapflow.evaluation.pipeline import runs_evaluator
from snapflow.evaluation.report import markdown_report
from snapflow.evaluation.results import (
    EpisodeResult,
    EvaluationReport,
    EvaluationRow,
    OfflineMetrics,
    SuccessCount,
    success_by_task,
)
from snapflow.flow.modes import NAIVE_1, SNAPFLOW_1, TEACHER_10
from snapflow.flow.solver import sample_actions
from snapflow.policies.mlp.processor import MLPProcessor
from snapflow.reporting.statistics import wilson_interval
from tests.evaluation.scripted import EPISODE_STEPS, ModalScriptedBenchmark, ScriptedEnv
from tests.training.fixtures import SYNTHETIC_TASKS


def test_success_is_counted_per_task_and_averaged_over_tasks():
    results = [EpisodeResult("a", 0, True, 5), EpisodeResult("a", 1, False, 9), EpisodeResult("b", 0, True, 3)]
    table = success_by_task(results)
    assert table == {"a": SuccessCount(1, 2, 0.5), "b": SuccessCount(1, 1, 1.0), "mean": SuccessCount(2, 3, 0.75)}


def test_path_modes_are_counted_per_task_with_a_last_column_for_neither():
    results = [
        EpisodeResult("a", 0, True, 5, 1),
        EpisodeResult("a", 1, False, 9, -1),
        EpisodeResult("b", 0, True, 3, 1),
    ]
    assert path_modes_by_task(results, 2) == {"a": [0, 1, 1], "b": [0, 1, 0]}
    assert path_modes_by_task([EpisodeResult("a", 0, True, 5)], 2) is None, "a benchmark without modes records none"
    row = EvaluationRow("p", "naive-1", 1, success_by_task(results), 1.0, path_modes=path_modes_by_task(results, 2))
    assert EvaluationRow.from_dict(row.to_dict()) == row
    plain = EvaluationRow("p", "naive-1", 1, success_by_task(results), 1.0)
    assert "path_modes" not in plain.to_dict() and EvaluationRow.from_dict(plain.to_dict()) == plain
    assert "mode" not in EpisodeResult("a", 0, True, 5).to_dict(), "logs of benchmarks without modes keep their form"


def test_each_episode_records_the_mode_its_environment_says_its_path_took(runs, tmp_path):
    """The evaluator asks each environment for its path's mode as the episode ends; an episode log keeps it."""
    _, teacher, _ = runs
    benchmark = ModalScriptedBenchmark()
    evaluator = ClosedLoopEvaluator(benchmark, list(SYNTHETIC_TASKS), 3, image_size=None)
    log = EpisodeLog(tmp_path / "log.jsonl", {"run": 1}, resume=False)
    results = evaluator.run(teacher.policy, teacher.processor, NAIVE_1, n_act=2, seed=1, progress=False, log=log)
    evaluator.close()
    expected = [env.path_mode() for env in benchmark.envs]
    assert [result.path_mode for result in results] == expected and set(expected) <= {-1, 0, 1}
    assert [
        r.path_mode for wave in EpisodeLog(log.path, {"run": 1}, resume=True).finished for r in wave.episodes
    ] == expected


def test_the_reports_rows_count_the_path_modes_and_show_their_coverage(runs, monkeypatch):
    """``snapflow eval`` on a benchmark with path modes: each row's counts per task, its shares and coverage error."""
    from snapflow.envs import factory
    from snapflow.evaluation.pipeline import evaluate

    monkeypatch.setitem(factory.BENCHMARKS, ModalScriptedBenchmark.name, ModalScriptedBenchmark)
    _, teacher, _ = runs
    benchmark = ModalScriptedBenchmark()
    tasks = list(SYNTHETIC_TASKS)
    report = evaluate([("naive", teacher, NAIVE_1)], benchmark, tasks, 3, n_act=2, progress=False, timing=False)
    counts = report.rows["naive"].path_modes
    expected = {task: [0, 0, 0] for task in tasks}
    for env in benchmark.envs:
        expected[env.task][env.path_mode()] += 1
    assert counts == expected and sum(map(sum, counts.values())) == 3 * len(tasks)
    rendered = markdown_report(report)
    assert "## Where the executed paths went" in rendered and "| row | up % | down % | neither % |" in rendered


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


def test_held_out_demonstrations_alone_are_scored_whole(scripted, runs, tmp_path):
    """A video sweep hands the evaluation its held-out episodes alone (their frames decoded): every one is scored,
    the same chunks as the policy's split of the whole set; split again, one episode a task would leave none."""
    from snapflow.evaluation.pipeline import evaluate

    data, teacher, _ = runs
    whole = Demonstrations.load(data)
    _, val_episodes = whole.split(teacher.val_fraction)
    whole.select(val_episodes).save(tmp_path / "held-out")
    run = [("teacher", teacher, TEACHER_10)]

    def offline(**options):
        report = evaluate(run, scripted, ["reach-v3"], 1, offline_samples=15, progress=False, timing=False, **options)
        return report.rows["teacher"].offline

    expected = offline_metrics(teacher.policy, ChunkData(whole, val_episodes, teacher.processor), TEACHER_10, 15, 0)
    assert offline(data=tmp_path / "held-out", data_held_out=True) == expected == offline(data=data)
    assert offline(data=tmp_path / "held-out") is None


def test_more_tasks_than_environments_run_a_group_of_tasks_at_a_time_every_slot_once(scripted, runs):
    _, teacher, _ = runs
    made = scripted.make_env

    def make_env(*args, **kwargs):  # at most one environment open at once: max_envs, below the two tasks
        assert not [env for env in scripted.envs if not env.closed], "a group's environments are closed first"
        return made(*args, **kwargs)

    scripted.make_env = make_env
    evaluator = ClosedLoopEvaluator(scripted, list(SYNTHETIC_TASKS), 2, image_size=None, max_envs=1)
    assert [list(group) for group in evaluator.task_groups] == [[0], [1]] and evaluator.wave_groups == [0, 0, 1, 1]
    results = evaluator.run(teacher.policy, teacher.processor, TEACHER_10, n_act=4, seed=3, progress=False)
    evaluator.close()
    assert [(r.task, r.variation) for r in results] == [(task, v) for task in SYNTHETIC_TASKS for v in range(2)]
    assert len(scripted.envs) == 2 and all(env.closed for env in scripted.envs), "one environment a task, made once"
    together = ClosedLoopEvaluator(scripted, list(SYNTHETIC_TASKS), 2, image_size=None, max_envs=4)
    assert len(together.task_groups) == 1, "as many environments as tasks: one group, the waves as before"
