"""The energy target (``snapflow-energy``): its score checked by hand, its extra rows and loss against a by-hand
computation on a real policy, and a small learning problem where it keeps two modes apart. The contract it shares with
every objective is in test_contract.py."""

from __future__ import annotations

import math
from dataclasses import replace

import pytest
import torch

from snapflow.errors import InvalidInputError
from snapflow.flow.time_sampling import UniformTimeSampler
from snapflow.nn import SnapFlowPolicy
from snapflow.objective.base import OneStepRows
from snapflow.objective.energy import EnergySnapFlowObjective, energy_score
from snapflow.objective.settings import DistillSettings
from snapflow.objective.snapflow import SnapFlowObjective, euler_shortcut_target
from snapflow.policies.mlp import MLPFlowModel, MLPPolicyConfig
from snapflow.training.recipes import student_settings, teacher_passes_spent
from tests.helpers import RecordingPolicy
from tests.objective.test_contract import make_problem


def test_energy_score_by_hand():
    """ES = mean_j |X_j - y| - (1 / (2 M (M - 1))) sum_{j != k} |X_j - X_k|, with weighted norms."""
    samples = torch.tensor([[[0.0, 0.0], [3.0, 4.0]], [[1.0, 1.0], [1.0, 1.0]]])
    reference = torch.tensor([[1.0, 7.0], [1.0, 4.0]])
    expected_first = (math.sqrt(1 + 49) + math.sqrt(4 + 9)) / 2 - 5 / 2
    score = energy_score(samples, reference)
    assert torch.allclose(score, torch.tensor([expected_first, 3.0]), atol=1e-5)
    # the second entry weighs nothing: |(a, b)|_w = |a| for the first row, and the second row's samples sit on y
    weights = torch.tensor([[1.0, 0.0], [1.0, 0.0]])
    assert torch.allclose(
        energy_score(samples, reference, weights), torch.tensor([(1 + 2) / 2 - 3 / 2, 0.0]), atol=1e-5
    )
    # three samples: pairs (0, 1), (0, 2), (1, 2) at 1, 2, 1, each counted twice over M (M - 1) = 6
    line = torch.tensor([[[0.0], [1.0], [2.0]]])
    assert torch.allclose(energy_score(line, torch.tensor([[1.0]])), torch.tensor([2 / 3 - (8 / 6) / 2]), atol=1e-5)


def test_the_true_distribution_scores_better_than_its_mean():
    """Properness, by hand and by sampling: y = +-1 equally. Samples of that law score E|X - y| - E|X - X'| / 2 =
    1 - 1/2 = 1/2; the mean 0, where a regression lands, scores 1 - 0 = 1."""
    generator = torch.Generator().manual_seed(0)
    signs = lambda *shape: torch.randint(0, 2, shape, generator=generator).float() * 2 - 1  # noqa: E731
    reference = signs(20_000, 1)
    spread = energy_score(signs(20_000, 2, 1), reference).mean()
    collapsed = energy_score(torch.zeros(20_000, 2, 1), reference).mean()
    assert abs(spread - 0.5) < 0.02 and abs(collapsed - 1.0) < 0.02


def test_extra_rows_share_the_gradient_pass_and_the_loss_adds_the_energy_term_by_hand():
    """The pass holds the FM rows, the one-step rows, then M - 1 more jumps 1 -> 0 of the one-step rows' observations;
    the loss is alpha L_FM + (1 - alpha) (lambda L_SC + w mean ES), each part recomputed here from the recorded inputs."""
    policy, observation, actions = make_problem("mlp", 6)
    objective = EnergySnapFlowObjective(
        alpha=0.5, consistency_weight=0.3, time_sampler=UniformTimeSampler(), energy_weight=2.0, energy_samples=3
    )
    recorder = RecordingPolicy(policy)
    output = objective(recorder, observation, actions, generator=torch.Generator().manual_seed(0))
    gradient_pass = recorder.calls[-1]
    assert gradient_pass.x.shape[0] == 3 + 3 * 3
    one_step = gradient_pass.x[3:6]
    extra = gradient_pass.x[6:]
    assert torch.equal(gradient_pass.t[3:], torch.ones(9)) and torch.equal(gradient_pass.s[3:], torch.zeros(9))
    context = policy.encode(observation)
    rows = torch.tensor([3, 4, 5, 3, 4, 5, 3, 4, 5])
    with torch.no_grad():
        jumps = torch.cat([one_step, extra])
        prediction = policy.velocity(jumps, torch.ones(9), torch.zeros(9), context[rows])
        velocity = lambda x, t, s: policy.velocity(x, t, s, context[3:])  # noqa: E731
        target = euler_shortcut_target(velocity, one_step, 2)
        consistency = (prediction[:3] - target).pow(2).mean()
        samples = (jumps - prediction).reshape(3, 3, -1).transpose(0, 1)
        energy = energy_score(samples, actions[3:].reshape(3, -1)).mean()
    assert torch.allclose(output.consistency_loss, consistency, rtol=1e-5)
    combined = 0.5 * output.flow_matching_loss + 0.5 * (0.3 * consistency + 2.0 * energy)
    assert torch.allclose(output.loss.detach(), combined, rtol=1e-5)


class TargetedAtLambdaZero(EnergySnapFlowObjective):
    """The energy objective as it was before lambda 0 skipped its target: the two-step target computed, weighted 0."""

    def one_step_rows(self, policy, observation, context, actions, noise, generator, progress) -> OneStepRows:  # noqa: ANN001
        rows = super().one_step_rows(policy, observation, context, actions, noise, generator, progress)
        velocity = lambda x, t, s: policy.velocity(x, t, s, context)  # noqa: E731
        return replace(rows, target=euler_shortcut_target(velocity, noise, self.target_steps))


def test_lambda_zero_spends_no_teacher_pass_and_changes_nothing_else():
    """At lambda 0 the consistency target is weighted 0, so it must cost nothing: the step makes one velocity call (the
    gradient pass) where the target costs two more no-grad passes, and its loss and every gradient are bit-identical to
    computing the target and weighting it 0."""
    losses, gradients, calls = [], [], []
    for kind in (EnergySnapFlowObjective, TargetedAtLambdaZero):
        policy, observation, actions = make_problem("mlp", 6)
        objective = kind(alpha=0.5, consistency_weight=0.0, time_sampler=UniformTimeSampler(), energy_weight=2.0)
        recorder = RecordingPolicy(policy)
        output = objective(recorder, observation, actions, generator=torch.Generator().manual_seed(0))
        output.loss.backward()
        losses.append(output.loss.detach())
        gradients.append([parameter.grad for parameter in policy.parameters()])
        calls.append([call.grad_enabled for call in recorder.calls])
    assert calls == [[True], [False, False, True]]
    assert torch.equal(losses[0], losses[1])
    assert all(torch.equal(ours, theirs) for ours, theirs in zip(*gradients, strict=True))
    assert objective.trains_jump and not replace(objective, energy_weight=0.0).trains_jump


def test_plain_snapflow_at_lambda_zero_spends_no_teacher_pass_either():
    policy, observation, actions = make_problem("mlp", 6)
    recorder = RecordingPolicy(policy)
    objective = SnapFlowObjective(alpha=0.5, consistency_weight=0.0, time_sampler=UniformTimeSampler())
    output = objective(recorder, observation, actions, generator=torch.Generator().manual_seed(0))
    assert len(recorder.calls) == 1 and output.consistency_loss == 0 and not objective.trains_jump
    paid = SnapFlowObjective(alpha=0.5, consistency_weight=0.1, time_sampler=UniformTimeSampler())
    recorder = RecordingPolicy(policy)
    paid(recorder, observation, actions, generator=torch.Generator().manual_seed(0))
    assert [call.grad_enabled for call in recorder.calls] == [False, False, True]


def test_settings_say_what_lambda_zero_trains_and_spends():
    energy = DistillSettings(target="energy", consistency_weight=0.0)
    assert energy.trains_jump and teacher_passes_spent(energy) == 0.0
    muted = DistillSettings(target="energy", consistency_weight=0.0, objective_options={"energy_weight": 0.0})
    assert not muted.trains_jump
    euler = DistillSettings(consistency_weight=0.0)
    assert not euler.trains_jump and teacher_passes_spent(euler) == 0.0
    assert teacher_passes_spent(DistillSettings(target="energy", consistency_weight=0.3)) == 2.0
    assert teacher_passes_spent(DistillSettings(target="bootstrap", target_steps=8, consistency_weight=0.0)) == 2.0


def test_settings_and_recipe_pick_it_and_refuse_what_it_does_not_take():
    settings = DistillSettings(target="energy", objective_options={"energy_weight": 2.0, "energy_samples": 4})
    objective = settings.objective(UniformTimeSampler())
    assert type(objective) is EnergySnapFlowObjective
    assert (objective.energy_weight, objective.energy_samples, objective.target_steps) == (2.0, 4, 2)
    _, modes = student_settings("modes")
    assert (modes.target, modes.consistency_weight, modes.alpha) == ("energy", 0.3, 0.5)
    assert modes.objective_options == {"energy_weight": 16.0, "energy_samples": 3}
    _, lean = student_settings("modes-lean")  # the energy term alone: no consistency target, no teacher pass
    assert (lean.target, lean.consistency_weight, lean.alpha) == ("energy", 0.0, 0.6)
    assert lean.objective_options == {"energy_weight": 16.0, "energy_samples": 4}
    assert lean.trains_jump and teacher_passes_spent(lean) == 0.0
    with pytest.raises(InvalidInputError, match="intermediate_jumps is not an option of the snapflow-energy"):
        DistillSettings(target="energy", intermediate_jumps=0.5)
    with pytest.raises(InvalidInputError, match="energy_samples must be an integer >= 2"):
        DistillSettings(target="energy", objective_options={"energy_samples": 1})


def test_the_energy_term_alone_learns_two_modes_a_regression_would_average():
    """A small learning problem: actions +-1 (equally likely, one context). A one-step jump trained by the energy term
    alone (lambda 0) puts most samples near a mode, on both sides; the plain jump regresses its two-step target of an
    untrained field and sits near the mean."""
    torch.manual_seed(0)
    generator = torch.Generator().manual_seed(0)
    model = MLPFlowModel(MLPPolicyConfig(observation_dim=1, action_dim=1, chunk_length=1, hidden_dim=32))
    student = SnapFlowPolicy(model)
    objective = EnergySnapFlowObjective(
        alpha=0.0, consistency_weight=0.0, time_sampler=UniformTimeSampler(), energy_weight=1.0, energy_samples=2
    )
    optimizer = torch.optim.Adam(student.parameters(), lr=3e-3)
    for _ in range(400):
        actions = torch.randint(0, 2, (64, 1, 1), generator=generator).float() * 2 - 1
        loss = objective(student, torch.zeros(64, 1), actions, generator=generator).loss
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
    with torch.no_grad():
        noise = torch.randn(2000, 1, 1, generator=generator)
        samples = noise - student.velocity(
            noise, torch.ones(2000), torch.zeros(2000), student.encode(torch.zeros(2000, 1))
        )
    samples = samples.flatten()
    near = ((samples.abs() - 1).abs() < 0.3).float().mean()
    positive = (samples > 0).float().mean()
    assert near > 0.7 and 0.3 < positive < 0.7, (near, positive)
