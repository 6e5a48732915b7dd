"""The SnapFlow objective against the paper's Algorithm 1 written out by hand."""

from __future__ import annotations

import pytest
import torch

from snapflow.flow import UniformTimeSampler
from snapflow.objective import SnapFlowObjective, euler_shortcut_target
from snapflow.objective.snapflow import jump_target
from tests.helpers import RecordingPolicy


def hand_computed_loss(policy, observation, actions, noise, time, n_fm, alpha, lam, clamp=None):
    """SPEC section 4, sample by sample, with no shared code path beyond the policy itself."""
    context = policy.encode(observation)
    fm_terms, sc_terms = [], []
    for i in range(actions.shape[0]):
        a, eps, c = actions[i : i + 1], noise[i : i + 1], context[i : i + 1]
        if i < n_fm:
            t = time[i : i + 1]
            x_t = (1 - t) * a + t * eps
            fm_terms.append(((policy.velocity(x_t, t, t, c) - (eps - a)) ** 2).mean())
        else:
            one, half, zero = torch.ones(1), torch.full((1,), 0.5), torch.zeros(1)
            with torch.no_grad():
                v_1 = policy.velocity(eps, one, one, c)
                if clamp:
                    v_1 = v_1.clamp(-clamp, clamp)
                v_half = policy.velocity(eps - 0.5 * v_1, half, half, c)
                if clamp:
                    v_half = v_half.clamp(-clamp, clamp)
            target = (v_1 + v_half) / 2
            sc_terms.append(((policy.velocity(eps, one, zero, c) - target) ** 2).mean())
    fm = torch.stack(fm_terms).mean() if fm_terms else torch.tensor(0.0)
    sc = torch.stack(sc_terms).mean() if sc_terms else torch.tensor(0.0)
    return alpha * fm + (1 - alpha) * lam * sc, fm, sc


@pytest.mark.parametrize("alpha, lam, clamp", [(0.5, 0.1, None), (0.3, 1.0, None), (0.5, 0.1, 0.05)])
def test_loss_equals_the_hand_computation(student, batch, alpha, lam, clamp):
    """The loss and both parts equal SPEC section 4 computed sample by sample, with and without a velocity clamp."""
    observation, actions = batch
    objective = SnapFlowObjective(alpha, lam, UniformTimeSampler(), teacher_velocity_clamp=clamp)
    n_fm = objective.num_flow_matching(6)
    noise, time = torch.randn(6, 3, 2), torch.rand(n_fm)
    output = objective(student, observation, actions, noise=noise, time=time)
    expected, fm, sc = hand_computed_loss(student, observation, actions, noise, time, n_fm, alpha, lam, clamp)
    assert output.num_flow_matching == n_fm and output.num_consistency == 6 - n_fm
    assert torch.allclose(output.loss, expected, atol=1e-6)
    assert torch.allclose(output.flow_matching_loss, fm, atol=1e-6)
    assert torch.allclose(output.consistency_loss, sc, atol=1e-6)


def test_consistency_target_is_the_two_step_euler_shortcut(student, batch):
    """The paper's target is (v_1 + v_.5) / 2 from the model's own FM velocities, and carries no gradient."""
    observation, _ = batch
    context = student.encode(observation)
    x_1 = torch.randn(6, 3, 2)
    one, half = torch.ones(6), torch.full((6,), 0.5)
    v_1 = student.velocity(x_1, one, one, context)
    v_half = student.velocity(x_1 - 0.5 * v_1, half, half, context)
    target = euler_shortcut_target(lambda x, t, s: student.velocity(x, t, s, context), x_1, steps=2)
    assert torch.allclose(target, (v_1 + v_half) / 2)
    assert not target.requires_grad


def test_gradient_flows_only_through_the_jump_pass(student, batch):
    """Two no-grad teacher passes in FM mode at t = 1 and t = .5, then one gradient pass whose consistency rows jump
    from the teacher's x_1 at t = 1 to s = 0; phi_s receives gradient."""
    observation, actions = batch
    recorder = RecordingPolicy(student)
    objective = SnapFlowObjective(time_sampler=UniformTimeSampler())
    output = objective(recorder, observation, actions)
    assert recorder.encodes == 1, "the context must be computed once and serve all three passes"
    teacher_1, teacher_half, student_pass = recorder.calls
    # the two teacher passes: FM mode (s = t) at t = 1 and t = 0.5, no autograd graph
    for call, t in ((teacher_1, 1.0), (teacher_half, 0.5)):
        assert not call.grad_enabled and not call.output.requires_grad
        assert torch.all(call.t == t) and torch.equal(call.s, call.t)
    # the gradient pass: FM rows at s = t, consistency rows at (s = 0, t = 1) from the same x_1 as the teacher
    n_fm = output.num_flow_matching
    assert student_pass.grad_enabled and student_pass.output.requires_grad
    assert torch.equal(student_pass.s[:n_fm], student_pass.t[:n_fm])
    assert torch.all(student_pass.t[n_fm:] == 1) and torch.all(student_pass.s[n_fm:] == 0)
    assert torch.equal(student_pass.x[n_fm:], teacher_1.x)
    output.loss.backward()
    assert all(p.grad is not None for p in student.target_time_embedding.parameters())


def test_alpha_one_is_plain_flow_matching(student, batch):
    """alpha = 1 trains the teacher: one pass, and the loss is the FM loss by hand."""
    observation, actions = batch
    recorder = RecordingPolicy(student)
    objective = SnapFlowObjective(alpha=1.0, time_sampler=UniformTimeSampler())
    noise, time = torch.randn(6, 3, 2), torch.rand(6)
    output = objective(recorder, observation, actions, noise=noise, time=time)
    assert len(recorder.calls) == 1 and output.num_consistency == 0
    x_t = (1 - time[:, None, None]) * actions + time[:, None, None] * noise
    prediction = student.velocity(x_t, time, time, student.encode(observation))
    assert torch.allclose(output.loss, ((prediction - (noise - actions)) ** 2).mean(), atol=1e-6)


def test_alpha_zero_is_consistency_only(student, batch):
    """alpha = 0 has no FM row and the loss is the consistency loss (lambda = 1)."""
    observation, actions = batch
    output = SnapFlowObjective(alpha=0.0, consistency_weight=1.0)(student, observation, actions)
    assert output.num_flow_matching == 0 and output.flow_matching_loss == 0
    assert torch.allclose(output.loss, output.consistency_loss)


def test_split_is_a_fixed_count_with_both_branches_present():
    """The FM share is round(alpha * B) half up, kept in [1, B - 1] for 0 < alpha < 1; a batch of one cannot split."""
    assert SnapFlowObjective(alpha=0.5).num_flow_matching(4) == 2
    assert SnapFlowObjective(alpha=0.5).num_flow_matching(5) == 3
    assert SnapFlowObjective(alpha=0.1).num_flow_matching(4) == 1
    assert SnapFlowObjective(alpha=0.9).num_flow_matching(4) == 3
    assert SnapFlowObjective(alpha=1.0).num_flow_matching(1) == 1
    with pytest.raises(ValueError, match="at least 2"):
        SnapFlowObjective(alpha=0.5).num_flow_matching(1)


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"alpha": 1.5}, "alpha"),
        ({"consistency_weight": -1}, "consistency_weight"),
        ({"teacher_velocity_clamp": 0}, "clamp"),
    ],
)
def test_invalid_settings_are_named(kwargs, message):
    """Out-of-range alpha, lambda and clamp are ValueErrors naming the setting."""
    with pytest.raises(ValueError, match=message):
        SnapFlowObjective(**kwargs)


def test_given_noise_and_time_shapes_are_checked(student, batch):
    """Given noise must match the actions and given times the FM rows; either mismatch is named."""
    observation, actions = batch
    objective = SnapFlowObjective()
    with pytest.raises(ValueError, match="noise"):
        objective(student, observation, actions, noise=torch.randn(6, 3, 3))
    with pytest.raises(ValueError, match="time must have shape"):
        objective(student, observation, actions, time=torch.rand(6))


def test_jump_target_is_the_k_step_euler_average_written_out_for_a_linear_field():
    """For v(x) = c x each Euler step scales x by (1 - c dt), so the K velocities average to
    x_t c (1 - (1 - c dt)^K) / (K c dt) with dt = (t - s) / K; at (1, 0) it is the paper's shortcut."""
    c, steps = 0.8, 4
    x_t = torch.randn(3, 2, 2)
    t, s = torch.tensor([1.0, 0.7, 0.4]), torch.tensor([0.0, 0.2, 0.35])
    dt = (t - s)[:, None, None] / steps
    expected = x_t * c * (1 - (1 - c * dt) ** steps) / (steps * c * dt)
    field = lambda x, time, target: c * x  # noqa: E731
    assert torch.allclose(jump_target(field, x_t, t, s, steps), expected, atol=1e-6)
    assert torch.allclose(
        jump_target(field, x_t[:1], t[:1], s[:1], steps), euler_shortcut_target(field, x_t[:1], steps)
    )


def test_intermediate_jumps_start_on_the_path_and_regress_the_euler_average_between_their_times(student, batch):
    """The first share of the one-step rows jump t -> s with 0 <= s < t <= 1 from x_t = (1 - t) a + t eps onto the
    K-step Euler average of the model's own velocities; the others are the paper's 1 -> 0 rows, unchanged."""
    observation, actions = batch
    context = student.encode(observation)
    noise = torch.randn_like(actions)
    objective = SnapFlowObjective(0.5, 0.1, UniformTimeSampler(), intermediate_jumps=0.5)
    rows = objective.one_step_rows(student, observation, context, actions, noise, torch.Generator().manual_seed(3), 0)
    inner = 3
    t, s = rows.t[:inner], rows.s[:inner]
    assert ((0 <= s) & (s < t) & (t <= 1)).all()
    assert torch.allclose(rows.x[:inner], (1 - t[:, None, None]) * actions[:inner] + t[:, None, None] * noise[:inner])
    velocity = lambda x, time, target: student.velocity(x, time, target, context[:inner])  # noqa: E731
    with torch.no_grad():
        x, total = rows.x[:inner], 0
        for k in range(2):
            time = t - (t - s) * k / 2
            v = velocity(x, time, time)
            total = total + v
            x = x - ((t - s) / 2)[:, None, None] * v
    by_hand = total / 2
    assert torch.allclose(rows.target[:inner], by_hand, atol=1e-6)
    paper = SnapFlowObjective(0.5, 0.1, UniformTimeSampler()).one_step_rows(
        student, observation, context, actions, noise, None, 0
    )
    assert torch.equal(rows.x[inner:], paper.x[inner:]) and torch.equal(rows.t[inner:], paper.t[inner:])
    assert torch.allclose(rows.target[inner:], paper.target[inner:], atol=1e-6)
    with pytest.raises(ValueError, match="intermediate_jumps must be in"):
        SnapFlowObjective(intermediate_jumps=1.5)
