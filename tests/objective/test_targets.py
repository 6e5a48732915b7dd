"""SnapFlow's one-step targets beyond the paper: K-step Euler, a schedule of K, and the bootstrapped target,
each against its math written out by hand."""

from __future__ import annotations

import pytest
import torch

from snapflow.flow import SamplingMode, UniformTimeSampler, euler_sample
from snapflow.jobs.toy import run_toy_experiment
from snapflow.jobs.toy_config import ToyConfig, toy_distill_settings
from snapflow.objective import BootstrappedSnapFlowObjective, SnapFlowObjective, euler_shortcut_target
from snapflow.objective.snapflow import stage_at
from snapflow.training.recipes import DistillSettings
from tests.helpers import RecordingPolicy


def test_k_step_target_averages_k_hand_written_euler_velocities_and_lands_where_the_solver_does(student, batch):
    """K = 4: the target is the mean of four hand-written Euler velocities, and x_1 - target is the solver's sample."""
    observation, _ = batch
    context = student.encode(observation)
    velocity = lambda x, t, s: student.velocity(x, t, s, context)  # noqa: E731
    x_1 = torch.randn(6, 3, 2)
    x, velocities = x_1, []
    for k in range(4):  # t = 1, .75, .5, .25
        t = torch.full((6,), 1 - k / 4)
        velocities.append(student.velocity(x, t, t, context))
        x = x - velocities[-1] / 4
    target = euler_shortcut_target(velocity, x_1, steps=4)
    assert torch.allclose(target, sum(velocities) / 4, atol=1e-6) and not target.requires_grad
    # the jump onto the target ends where the K-step teacher ends
    assert torch.allclose(x_1 - target, euler_sample(velocity, x_1, SamplingMode(4, jump=False)), atol=1e-5)


@pytest.mark.parametrize("steps", [2, 4, 8])
def test_euler_target_costs_k_no_grad_passes_and_one_gradient_pass(student, batch, steps):
    """A K-step target costs K no-grad passes at t = 1, 1 - 1/K, ..., then one gradient pass."""
    observation, actions = batch
    recorder = RecordingPolicy(student)
    SnapFlowObjective(time_sampler=UniformTimeSampler(), target_steps=steps)(recorder, observation, actions)
    assert [call.grad_enabled for call in recorder.calls] == [False] * steps + [True]
    assert [call.t[0].item() for call in recorder.calls[:-1]] == pytest.approx([1 - k / steps for k in range(steps)])


def test_schedule_raises_k_in_equal_stages_of_training(student, batch):
    """A schedule (2, 4, 8) splits training into equal thirds; the call's progress picks K, and K its passes."""
    assert [stage_at((2, 4, 8), p) for p in (0.0, 0.33, 0.34, 0.66, 0.67, 0.999, 1.0)] == [2, 2, 4, 4, 8, 8, 8]
    objective = SnapFlowObjective(time_sampler=UniformTimeSampler(), target_steps=[2, 4, 8])
    assert objective.target_steps == (2, 4, 8) and objective.schedule(0.5) == {"target_steps": 4}
    observation, actions = batch
    for progress, expected in ((0.1, 2), (0.5, 4), (0.9, 8)):
        recorder = RecordingPolicy(student)
        objective(recorder, observation, actions, progress=progress)
        assert len(recorder.calls) == expected + 1


def test_bootstrapped_target_by_hand(student, batch):
    """target_steps = 4: jumps of 1 (from t = 1, through the model's own half-jumps) and of 1/2 (from t = 1 or
    1/2, through instantaneous velocities); three passes, rows at the draws the sampler made."""
    observation, actions = batch
    recorder = RecordingPolicy(student)
    objective = BootstrappedSnapFlowObjective(
        alpha=0.0, consistency_weight=1.0, time_sampler=UniformTimeSampler(), target_steps=4
    )
    noise = torch.randn(6, 3, 2)
    output = objective(recorder, observation, actions, noise=noise, generator=torch.Generator().manual_seed(0))
    first, second, gradient_pass = recorder.calls
    assert not first.grad_enabled and not second.grad_enabled and gradient_pass.grad_enabled
    t, s = gradient_pass.t, gradient_pass.s
    h = t - s
    assert set(h.tolist()) == {1.0, 0.5}, "both jump sizes are drawn"
    assert torch.all((t / h) == (t / h).round()) and torch.all(s >= 0)
    context = student.encode(observation)
    losses = []
    for i in range(6):
        a, eps, c, ti, hi = actions[i : i + 1], noise[i : i + 1], context[i : i + 1], t[i : i + 1], h[i : i + 1]
        x_t = (1 - ti) * a + ti * eps
        assert torch.allclose(gradient_pass.x[i : i + 1], x_t)
        m = ti - hi / 2
        with torch.no_grad():
            if hi.item() == 0.5:  # finest level: SnapFlow's two Euler velocities on [t - 1/2, t]
                u_1 = student.velocity(x_t, ti, ti, c)
                u_2 = student.velocity(x_t - hi / 2 * u_1, m, m, c)
            else:  # the one-step jump: the model's own jumps 1 -> 1/2 and 1/2 -> 0
                u_1 = student.velocity(x_t, ti, m, c)
                u_2 = student.velocity(x_t - hi / 2 * u_1, m, ti - hi, c)
        losses.append(((student.velocity(x_t, ti, ti - hi, c) - (u_1 + u_2) / 2) ** 2).mean())
    assert torch.allclose(output.loss, torch.stack(losses).mean(), atol=1e-6)


def test_bootstrapped_target_with_two_steps_is_snapflow(student, batch):
    """With K = 2 the bootstrapped objective has one level, the finest: exactly the paper's loss."""
    observation, actions = batch
    noise = torch.randn(6, 3, 2)
    time = torch.rand(3)
    paper = SnapFlowObjective(time_sampler=UniformTimeSampler())(student, observation, actions, noise=noise, time=time)
    bootstrapped = BootstrappedSnapFlowObjective(time_sampler=UniformTimeSampler(), target_steps=2)(
        student, observation, actions, noise=noise, time=time, generator=torch.Generator().manual_seed(0)
    )
    assert torch.allclose(paper.loss, bootstrapped.loss, atol=1e-6)


@pytest.mark.parametrize(
    "settings, message",
    [
        ({"target": "oracle"}, "unknown SnapFlow target 'oracle'"),
        ({"target_steps": 0}, "target_steps must be a positive integer"),
        ({"target_steps": []}, "target_steps must be a positive integer"),
        ({"target": "bootstrap", "target_steps": 6}, "power of two >= 2, got 6"),
        ({"target": "bootstrap", "target_steps": [2, 4]}, r"grows by itself .* not the schedule \[2, 4\]"),
        (
            {"target": "bootstrap", "teacher_velocity": "conditional"},
            "teacher_velocity is not an option of the snapflow-bootstrap objective",
        ),
        ({"method": "meanflow", "target_steps": 4}, "target_steps is not an option of the meanflow objective"),
        ({"method": "meanflow", "target": "bootstrap"}, "target is an option of the snapflow method only"),
        ({"method": "meanflow", "intermediate_jumps": 0.5}, "intermediate_jumps is not an option of the meanflow"),
        ({"intermediate_jumps": 2.0}, "intermediate_jumps must be in"),
    ],
)
def test_bad_target_settings_are_named(settings, message):
    """Target settings the objectives cannot honour are ValueErrors saying why."""
    with pytest.raises(ValueError, match=message):
        DistillSettings(**settings)


def test_intermediate_jumps_reach_the_snapflow_objective_from_the_settings():
    objective = DistillSettings(intermediate_jumps=0.25).objective(UniformTimeSampler())
    assert isinstance(objective, SnapFlowObjective) and objective.intermediate_jumps == 0.25


@pytest.mark.slow
def test_more_euler_steps_in_the_target_bring_the_one_step_jump_closer_to_the_data():
    """Learning test on the multimodal toy: an 8-step target beats the paper's 2-step target, which cannot
    beat the 2-step teacher it imitates."""
    distances = {
        steps: run_toy_experiment(
            ToyConfig(distill_steps=1000, distill=toy_distill_settings(consistency_weight=1.0, target_steps=steps)),
            progress=False,
        ).distances
        for steps in (2, 8)
    }
    print({steps: round(d["snapflow-1"], 4) for steps, d in distances.items()})
    assert distances[8]["snapflow-1"] < 0.75 * distances[2]["snapflow-1"]
