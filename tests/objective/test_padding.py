"""A policy whose chunks hold padding (``PaddedActions``, GR00T's ``action_mask``): both of the objective's means are
taken over the entries it weighs only, written out here by hand."""

from __future__ import annotations

import torch
from torch import Tensor, nn

from snapflow.flow import UniformTimeSampler
from snapflow.objective import SnapFlowObjective
from snapflow.protocol import PaddedActions


class PaddedStudent(nn.Module):
    """The test student with a fixed mask: the last action width is padding in every row, and the last chunk step
    (past an episode's end) in rows 1 and 4."""

    def __init__(self, student: nn.Module, actions: Tensor) -> None:
        super().__init__()
        self.student = student
        self.mask = torch.ones_like(actions)
        self.mask[:, :, -1] = 0
        self.mask[[1, 4], -1] = 0

    def encode(self, observation):
        return self.student.encode(observation)

    def velocity(self, x_t, t, s, context):
        return self.student.velocity(x_t, t, s, context)

    def action_weights(self, observation) -> Tensor:
        return self.mask


def masked_loss(policy, observation, actions, noise, time, n_fm, alpha, lam):
    """SPEC section 4 with padding: FM over every weighted entry of the FM rows at once (GR00T's own
    sum(mask * e) / sum(mask)), each one-step row's squared error over its own weighted entries, then their mean."""
    context, mask = policy.encode(observation), policy.mask
    a, eps, t = actions[:n_fm], noise[:n_fm], time[:, None, None]
    x_t = (1 - t) * a + t * eps
    fm_error = (policy.velocity(x_t, time, time, context[:n_fm]) - (eps - a)) ** 2
    fm = (fm_error * mask[:n_fm]).sum() / mask[:n_fm].sum()
    rows = []
    for i in range(n_fm, actions.shape[0]):
        e, c, one, half, zero = (
            noise[i : i + 1],
            context[i : i + 1],
            torch.ones(1),
            torch.full((1,), 0.5),
            torch.zeros(1),
        )
        with torch.no_grad():
            v_1 = policy.velocity(e, one, one, c)
            target = (v_1 + policy.velocity(e - 0.5 * v_1, half, half, c)) / 2
        error = (policy.velocity(e, one, zero, c) - target) ** 2
        rows.append((error * mask[i]).sum() / mask[i].sum())
    sc = torch.stack(rows).mean()
    return alpha * fm + (1 - alpha) * lam * sc, fm, sc


def test_a_padded_chunks_loss_weighs_its_real_entries_alone(student, batch):
    observation, actions = batch
    padded = PaddedStudent(student, actions)
    assert isinstance(padded, PaddedActions) and not isinstance(student, PaddedActions)
    objective = SnapFlowObjective(0.5, 0.1, UniformTimeSampler())
    noise, time = torch.randn(6, 3, 2, generator=torch.Generator().manual_seed(3)), torch.rand(3)
    output = objective(padded, observation, actions, noise=noise, time=time)
    expected, fm, sc = masked_loss(padded, observation, actions, noise, time, 3, 0.5, 0.1)
    assert torch.allclose(output.flow_matching_loss, fm, atol=1e-6)
    assert torch.allclose(output.consistency_loss, sc, atol=1e-6)
    assert torch.allclose(output.loss, expected, atol=1e-6)
    # the unpadded student's loss, which weighs every entry, is another
    assert not torch.allclose(objective(student, observation, actions, noise=noise, time=time).loss, output.loss)


def test_a_mask_of_ones_gives_the_plain_loss(student, batch):
    observation, actions = batch
    padded = PaddedStudent(student, actions)
    padded.mask = torch.ones(1, 1, 1)  # broadcast to every entry
    objective = SnapFlowObjective(0.5, 0.1, UniformTimeSampler())
    noise, time = torch.randn(6, 3, 2, generator=torch.Generator().manual_seed(3)), torch.rand(3)
    plain = objective(student, observation, actions, noise=noise, time=time)
    assert torch.allclose(objective(padded, observation, actions, noise=noise, time=time).loss, plain.loss, atol=1e-7)
