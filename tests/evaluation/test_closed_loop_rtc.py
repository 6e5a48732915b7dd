"""The closed-loop evaluator under an inference delay: when chunks are planned, what they continue and which of their
actions run, by hand on the scripted benchmark; and the settings it refuses."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from snapflow.errors import InvalidInputError
from snapflow.evaluation.closed_loop import ClosedLoopEvaluator
from snapflow.evaluation.episode_log import EpisodeLog
from snapflow.evaluation.switches import switch_smoothness
from snapflow.flow.modes import NAIVE_1, SNAPFLOW_1, TEACHER_10
from snapflow.flow.realtime import RealTimeChunking, sample_chunk_continuing
from snapflow.flow.solver import sample_actions
from tests.evaluation.scripted import EPISODE_STEPS
from tests.training.fixtures import SYNTHETIC_TASKS


def _run(scripted, policy, processor, mode, n_act, rtc, seed=3):
    encodes = []
    encode = policy.encode
    policy.encode = lambda observation: encodes.append(len(observation)) or encode(observation)
    try:
        evaluator = ClosedLoopEvaluator(scripted, list(SYNTHETIC_TASKS), 2, image_size=None)
        results = evaluator.run(policy, processor, mode, n_act=n_act, seed=seed, progress=False, rtc=rtc)
        evaluator.close()
    finally:
        del policy.encode  # the module's shared policy gets its own method back
    return results, encodes


# (delay, the index in the previous chunk each next chunk continues from, the (chunk, action) run at each step) with
# n_act 2, chunks of 4 and 6 steps an episode
SCHEDULES = {
    "delay 1": (1, [1, 2, 2], [(0, 0), (0, 1), (1, 1), (1, 2), (2, 1), (2, 2)]),
    "no delay: the rest past the executed actions still guides": (
        0,
        [2, 2],
        [(0, 0), (0, 1), (1, 0), (1, 1), (2, 0), (2, 1)],
    ),
    "delay = n_act: the second chunk planned before any step": (
        2,
        [0, 2, 2],
        [(0, 0), (0, 1), (1, 2), (1, 3), (2, 2), (2, 3)],
    ),
}


@pytest.mark.parametrize("case", SCHEDULES, ids=list(SCHEDULES))
def test_a_delayed_chunk_is_planned_with_d_actions_queued_and_runs_from_its_action_d(scripted, runs, case):
    delay, starts, executed = SCHEDULES[case]
    _, teacher, _ = runs
    policy, processor = teacher.policy, teacher.processor
    rtc = RealTimeChunking(delay, "inpaint")
    results, encodes = _run(scripted, policy, processor, NAIVE_1, 2, rtc)
    assert [r.steps for r in results] == [EPISODE_STEPS] * 4
    assert encodes == [4] * (len(starts) + 1), "every environment plans in one batch"
    # by hand: the first chunk plain, each next one continuing the rest of the chunk before it
    generator = torch.Generator().manual_seed(3)
    envs = scripted.envs
    observation = processor.observation(np.stack([env.state for env in envs]), [env.instruction for env in envs])
    context = policy.encode(observation)

    def noise():
        return torch.randn(4, processor.chunk_length, processor.action_dim, generator=generator)

    with torch.no_grad():
        chunks = [sample_actions(policy, observation, noise(), NAIVE_1)]
        for start in starts:
            chunks.append(sample_chunk_continuing(policy, context, noise(), NAIVE_1, chunks[-1][:, start:], rtc))
    actions = [processor.unnormalize_actions(chunk).numpy() for chunk in chunks]
    for row, env in enumerate(envs):
        expected = np.stack([actions[chunk][row, index] for chunk, index in executed])
        assert np.allclose(np.stack(env.actions), expected, atol=1e-6)
    if delay:  # the delayed actions of a chunk are those of the chunk before it that ran meanwhile
        assert np.allclose(actions[1][:, :delay], actions[0][:, starts[0] : starts[0] + delay], atol=1e-5)
    else:  # the second chunk's own noise, sampled without the rest of the first: its first action differs
        generator.manual_seed(3)
        noise()
        plain = processor.unnormalize_actions(sample_actions(policy, observation, noise(), NAIVE_1)).numpy()
        assert not np.allclose(actions[1][:, 0], plain[:, 0], atol=1e-3), "the first chunk's rest pulls it"


def test_guided_and_inpainted_runs_go_to_the_end_of_each_episode(scripted, runs):
    _, teacher, student = runs
    results, encodes = _run(scripted, teacher.policy, teacher.processor, TEACHER_10, 2, RealTimeChunking(2, "guided"))
    assert encodes == [4, 4, 4, 4], "steps 0 (twice: nothing runs before the second chunk is computed), 2 and 4"
    plain, _ = _run(scripted, teacher.policy, teacher.processor, TEACHER_10, 2, None)
    delayed, _ = _run(scripted, student.policy, student.processor, SNAPFLOW_1, 2, RealTimeChunking(0, "inpaint"))
    assert [r.steps for r in plain] == [r.steps for r in delayed] == [EPISODE_STEPS] * 4


def test_each_episode_measures_its_chunk_switches_and_a_resumed_run_reads_them_back(scripted, runs, tmp_path):
    """With ``switches`` each episode's result holds the jump and jerk of the actions it executed (the scripted
    environments record them), and its episode log keeps them for a resumed run."""
    _, teacher, _ = runs
    evaluator = ClosedLoopEvaluator(scripted, list(SYNTHETIC_TASKS), 2)
    log = EpisodeLog(tmp_path / "log.jsonl", {"run": 1}, resume=False)
    rtc = RealTimeChunking(1, "guided")
    results = evaluator.run(
        teacher.policy, teacher.processor, TEACHER_10, n_act=2, progress=False, log=log, rtc=rtc, switches=True
    )
    evaluator.close()
    for env, result in zip(scripted.envs, results, strict=True):
        assert result.switches == switch_smoothness(np.stack(env.actions), 2) and result.switches.switches == 2
    assert [e for wave in EpisodeLog(log.path, {"run": 1}, resume=True).finished for e in wave.episodes] == results


def test_settings_the_evaluator_cannot_run_are_refused(scripted, runs):
    _, teacher, student = runs
    evaluator = ClosedLoopEvaluator(scripted, ["reach-v3"], 1)
    cases = [
        (teacher, NAIVE_1, 2, RealTimeChunking(3, "inpaint"), "delay <= n_act"),
        (teacher, NAIVE_1, 3, RealTimeChunking(2, "inpaint"), "n_act \\+ delay <= the policy's chunk length 4"),
        (student, SNAPFLOW_1, 2, RealTimeChunking(1, "guided"), "steers Euler steps"),
        (student, SNAPFLOW_1, 2, RealTimeChunking(1, "trained"), "MLPFlowModel takes one time a chunk"),
    ]
    for opened, mode, n_act, rtc, message in cases:
        with pytest.raises(InvalidInputError, match=message):
            evaluator.run(opened.policy, opened.processor, mode, n_act=n_act, progress=False, rtc=rtc)
    evaluator.close()


def test_the_pipeline_records_the_setting_each_run_resolved_and_resumes_only_the_same(scripted, runs, tmp_path):
    import json

    from snapflow.evaluation.pipeline import evaluate
    from snapflow.evaluation.report import markdown_report

    _, teacher, student = runs
    labelled = [("teacher 10-NFE", teacher, TEACHER_10), ("SnapFlow 1-NFE", student, SNAPFLOW_1)]

    def delayed(rtc, resume=False):
        return evaluate(
            labelled, scripted, ["reach-v3"], 1, n_act=2, progress=False, timing=False, episode_logs=tmp_path,
            resume=resume, rtc=rtc,
        )  # fmt: skip

    assert student.known_prefix_delay == 0 == teacher.known_prefix_delay, "distilled without known prefixes"
    report = delayed(RealTimeChunking(1))
    assert report.to_dict()["rtc"] == RealTimeChunking(1).to_dict()
    rendered = markdown_report(report)
    assert "Inference delay of 1 action(s)" in rendered and "## How smoothly the chunks joined" in rendered
    assert "| teacher 10-NFE | 2 |" in rendered
    kinds = [
        json.loads(path.read_text().splitlines()[0])["identity"]["rtc"]["kind"] for path in sorted(tmp_path.iterdir())
    ]
    assert kinds == ["guided", "inpaint"], "each run logs the kind it ran"
    with pytest.raises(ValueError, match="differs in rtc"):
        delayed(RealTimeChunking(2), resume=True)
    with pytest.raises(InvalidInputError, match="steers Euler steps"):
        delayed(RealTimeChunking(1, "guided"))
    assert "rtc" not in evaluate(labelled[:1], scripted, ["reach-v3"], 1, progress=False, timing=False).to_dict()
    assert all(row.switches.switches == 2 for row in report.rows.values()), "an episode of 6 steps, 2 a chunk"


def test_a_log_written_before_switches_were_measured_resumes_to_a_row_without_them(scripted, runs, tmp_path):
    import json

    from snapflow.evaluation.pipeline import evaluate

    _, teacher, _ = runs

    def delayed(resume: bool):
        report = evaluate(
            [("teacher 10-NFE", teacher, TEACHER_10)], scripted, ["reach-v3"], 1, n_act=2, progress=False,
            timing=False, episode_logs=tmp_path, resume=resume, rtc=RealTimeChunking(1),
        )  # fmt: skip
        return report.rows["teacher 10-NFE"]

    assert delayed(resume=False).switches is not None
    (log,) = tmp_path.iterdir()
    header, *waves = log.read_text().splitlines()
    older = [json.loads(wave) for wave in waves]
    for wave in older:
        for episode in wave["episodes"]:
            del episode["switches"]
    log.write_text("\n".join([header, *map(json.dumps, older)]) + "\n")
    resumed = delayed(resume=True)
    assert resumed.switches is None and resumed.success["mean"].episodes == 1
