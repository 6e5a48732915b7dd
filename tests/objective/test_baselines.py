"""The one-step baselines and the ablation objectives against their formulas written out by hand."""

from __future__ import annotations

import copy

import pytest
import torch

from snapflow.flow import UniformTimeSampler
from snapflow.jobs.toy import run_toy_experiment
from snapflow.jobs.toy_config import ToyConfig, toy_distill_settings
from snapflow.objective import ConsistencyDistillationObjective, MeanFlowObjective, SnapFlowObjective
from snapflow.training.recipes import DistillSettings


def test_conditional_velocity_ablation_regresses_the_jump_on_eps_minus_a(student, batch):
    """teacher_velocity="conditional" (the paper's Table 5 ablation): the jump F(eps, 1, 0) regresses eps - a."""
    observation, actions = batch
    objective = SnapFlowObjective(
        alpha=0.5, consistency_weight=1.0, time_sampler=UniformTimeSampler(), teacher_velocity="conditional"
    )
    noise, time = torch.randn(6, 3, 2), torch.rand(3)
    output = objective(student, observation, actions, noise=noise, time=time)
    context = student.encode(observation)
    jump = student.velocity(noise[3:], torch.ones(3), torch.zeros(3), context[3:])
    expected = ((jump - (noise[3:] - actions[3:])) ** 2).mean()
    assert torch.allclose(output.consistency_loss, expected, atol=1e-6)


def test_consistency_distillation_loss_and_ema_target_by_hand(student, batch):
    """CD regresses f(x_hi, t_hi) on the EMA network's f(x_lo, t_lo) one teacher Euler step below, weighted t_hi^2;
    the EMA network starts as a copy and follows the online weights in training mode only."""
    observation, actions = batch
    objective = ConsistencyDistillationObjective(
        alpha=0.5, consistency_weight=1.0, time_sampler=UniformTimeSampler(), num_intervals=4, ema_decay=0.9
    )
    noise, time = torch.randn(6, 3, 2), torch.rand(3)
    generator = torch.Generator().manual_seed(3)
    output = objective(student, observation, actions, noise=noise, time=time, generator=generator)

    # the same interval draw, then the CD formula on the consistency rows 3..5
    interval = (torch.rand(3, generator=torch.Generator().manual_seed(3)) * 4).floor()
    t_hi, t_lo = (interval + 1) / 4, interval / 4
    context = student.encode(observation)[3:]
    a, eps = actions[3:], noise[3:]
    x_hi = (1 - t_hi[:, None, None]) * a + t_hi[:, None, None] * eps
    with torch.no_grad():
        x_lo = x_hi - (t_hi - t_lo)[:, None, None] * student.velocity(x_hi, t_hi, t_hi, context)
        # the EMA network is the online one at the first call
        f_target = x_lo - t_lo[:, None, None] * student.velocity(x_lo, t_lo, torch.zeros(3), context)
    f_online = x_hi - t_hi[:, None, None] * student.velocity(x_hi, t_hi, torch.zeros(3), context)
    expected = ((f_online - f_target) ** 2).flatten(1).mean(1).mean()
    assert torch.allclose(output.consistency_loss, expected, atol=1e-6)

    # the target network follows the online weights by EMA in training mode only
    target = objective._target
    before = copy.deepcopy(target.state_dict())
    with torch.no_grad():
        for parameter in student.parameters():
            parameter.add_(1.0)
    student.eval()
    objective(student, observation, actions)
    assert all(torch.equal(before[name], value) for name, value in target.state_dict().items())
    student.train()
    objective(student, observation, actions)
    online = dict(student.named_parameters())
    for name, value in target.named_parameters():
        assert torch.allclose(value, 0.9 * before[name] + 0.1 * online[name], atol=1e-6)


@pytest.mark.parametrize("power", [0.0, 1.0])
def test_meanflow_target_is_the_mean_flow_identity(student, batch, power):
    """MeanFlow regresses F(x_t, t, s) on v - (t - s) d/dt u(x_t, t, s), with and without its adaptive weighting."""
    observation, actions = batch
    objective = MeanFlowObjective(
        alpha=0.5, consistency_weight=1.0, time_sampler=UniformTimeSampler(), adaptive_power=power
    )
    noise, time = torch.randn(6, 3, 2), torch.rand(3)
    generator = torch.Generator().manual_seed(5)
    output = objective(student, observation, actions, noise=noise, time=time, generator=generator)

    draws = torch.Generator().manual_seed(5)
    first, second = torch.rand(3, generator=draws), torch.rand(3, generator=draws)
    t, s = torch.maximum(first, second), torch.minimum(first, second)
    context = student.encode(observation)[3:]
    x_t = (1 - t[:, None, None]) * actions[3:] + t[:, None, None] * noise[3:]
    v = student.velocity(x_t, t, t, context).detach()
    # the total derivative d/dt u(x_t, t, s) along (v, 1), by reverse-mode autograd's double-vjp trick (the
    # objective uses forward mode); finite differences are too coarse for the high-frequency time features
    _, du_dt = torch.autograd.functional.jvp(
        lambda x, time: student.velocity(x, time, s, context), (x_t, t), (v, torch.ones_like(t))
    )
    target = v - (t - s)[:, None, None] * du_dt
    error = ((student.velocity(x_t, t, s, context) - target) ** 2).flatten(1).mean(1)
    expected = (error / (error + 1e-3) ** power).mean()  # MeanFlow's adaptive weighting, sg(e + c) ** -p
    assert torch.allclose(output.consistency_loss, expected, rtol=1e-5)


@pytest.mark.slow
def test_consistency_distillation_learns_a_one_step_jump_on_the_toy_mixture():
    """Learning test: its 1-NFE samples end far closer to the data than the naive one-step teacher's."""
    result = run_toy_experiment(
        ToyConfig(distill_steps=1000, distill=toy_distill_settings(method="consistency-distillation")), progress=False
    )
    print(
        f"energy distance: naive-1 {result.distances['naive-1']:.4f}, "
        f"consistency distillation 1-NFE {result.distances['snapflow-1']:.4f}"
    )
    assert result.distances["snapflow-1"] < 0.8 * result.distances["naive-1"]


@pytest.mark.parametrize(
    "settings, message",
    [
        ({"method": "dance"}, "unknown distillation method 'dance'"),
        ({"teacher_velocity": "imagined"}, "teacher_velocity must be one of"),
        (
            {"method": "meanflow", "teacher_velocity": "conditional"},
            "teacher_velocity is not an option of the meanflow objective",
        ),
    ],
)
def test_bad_distill_settings_are_named(settings, message):
    """A method the settings do not know, a bad option value, and an option the chosen method lacks are named."""
    with pytest.raises(ValueError, match=message):
        DistillSettings(**settings)


@pytest.mark.parametrize(
    "objective, kwargs, message",
    [
        (ConsistencyDistillationObjective, {"num_intervals": 0}, "num_intervals"),
        (ConsistencyDistillationObjective, {"ema_decay": 1.0}, "ema_decay"),
        (MeanFlowObjective, {"adaptive_power": -1.0}, "adaptive_power"),
        (MeanFlowObjective, {"alpha": 2.0}, "alpha"),
    ],
)
def test_bad_baseline_settings_are_named(objective, kwargs, message):
    """Each baseline checks its own values and names the one out of range."""
    with pytest.raises(ValueError, match=message):
        objective(**kwargs)
