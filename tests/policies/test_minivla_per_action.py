"""MiniVLA with a time per action: the same velocity as one time a row where the times agree, the MLP policy refused
by name, and a tiny MiniVLA that learns to continue a given prefix (real-time chunking trained in)."""

from __future__ import annotations

import pytest
import torch

from snapflow.errors import InvalidInputError
from snapflow.flow.known_prefix import KnownPrefixPolicy, sample_continuing
from snapflow.flow.modes import SNAPFLOW_1
from snapflow.nn import SnapFlowPolicy
from snapflow.objective.settings import DistillSettings
from snapflow.policies.minivla import MiniVLA, MiniVLAConfig
from snapflow.protocol import PerActionTimes
from tests.helpers import make_model
from tests.policies.test_minivla import CONFIG, _observation, _randomise_modulation


def _student() -> SnapFlowPolicy:
    torch.manual_seed(0)
    model = MiniVLA(CONFIG)
    _randomise_modulation(model)
    student = SnapFlowPolicy(model)
    with torch.no_grad():  # phi_s starts at zero: give it weights so that s matters
        for parameter in student.target_time_embedding.parameters():
            parameter.normal_(0, 0.1)
    return student.eval()


def test_per_action_times_equal_to_a_rows_time_give_that_rows_velocity():
    student = _student()
    assert isinstance(student, PerActionTimes) and student.per_action_times_refusal is None
    context = student.encode(_observation())
    x = torch.randn(4, CONFIG.chunk_length, CONFIG.action_dim, generator=torch.Generator().manual_seed(1))
    t, s = torch.tensor([1.0, 0.7, 0.4, 0.1]), torch.tensor([0.5, 0.0, 0.4, 0.05])
    each = (t[:, None].expand(-1, CONFIG.chunk_length), s[:, None].expand(-1, CONFIG.chunk_length))
    with torch.no_grad():
        row = student.velocity(x, t, s, context)
        per_action = student.velocity_per_action(x, *each, context)
        one_late = each[0].clone()
        one_late[:, 0] = 0.0
        moved = student.velocity_per_action(x, one_late, each[1], context)
    assert torch.allclose(per_action, row, atol=1e-6)
    assert not torch.allclose(moved[:, 1:], row[:, 1:], atol=1e-4), "one action's time reaches the others"


def test_a_model_with_one_time_a_chunk_is_refused_naming_the_model():
    student = SnapFlowPolicy(make_model())
    assert student.per_action_times_refusal == "MLPFlowModel takes one time a chunk"
    with pytest.raises(InvalidInputError, match="MLPFlowModel takes one time a chunk"):
        student.velocity_per_action(torch.zeros(1, 3, 2), torch.zeros(1, 3), torch.zeros(1, 3), None)
    with pytest.raises(InvalidInputError, match="MLPFlowModel takes one time a chunk"):
        KnownPrefixPolicy(student, torch.zeros(1, 3, 2), torch.zeros(1, 3, dtype=torch.bool))


TOY = MiniVLAConfig(
    state_dim=2,
    action_dim=1,
    chunk_length=6,
    prefix_width=16,
    expert_width=32,
    num_layers=1,
    num_heads=2,
    head_dim=8,
    max_instruction_tokens=2,
)


def _toy_observation(batch: int) -> dict[str, torch.Tensor]:
    return {
        "state": torch.zeros(batch, 2),
        "tokens": torch.ones(batch, 2, dtype=torch.long),
        "token_mask": torch.ones(batch, 2, dtype=torch.bool),
    }


def _bimodal(count: int, generator: torch.Generator) -> torch.Tensor:
    """Chunks that hold +1 or -1 throughout, by a coin the observation does not show."""
    signs = torch.randint(0, 2, (count, 1, 1), generator=generator) * 2.0 - 1.0
    return signs.expand(-1, 6, 1) + 0.05 * torch.randn(count, 6, 1, generator=generator)


@pytest.mark.slow
def test_a_tiny_minivla_distilled_with_known_prefixes_continues_them():
    from snapflow.flow.time_sampling import UniformTimeSampler

    torch.manual_seed(0)
    student, generator = SnapFlowPolicy(MiniVLA(TOY)), torch.Generator().manual_seed(1)
    objective = DistillSettings(consistency_weight=1.0, rtc_max_delay=2).objective(UniformTimeSampler())
    optimizer = torch.optim.Adam(student.parameters(), lr=3e-3)
    for _ in range(300):
        loss = objective(student, _toy_observation(64), _bimodal(64, generator), generator=generator).loss
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
    noise = torch.randn(200, 6, 1, generator=torch.Generator().manual_seed(9))
    previous = torch.cat([torch.ones(100, 6, 1), -torch.ones(100, 6, 1)])
    with torch.no_grad():
        context = student.encode(_toy_observation(200))
        given = sample_continuing(student, context, noise, SNAPFLOW_1, previous, 2)
        free = sample_continuing(student, context, noise, SNAPFLOW_1, previous, 0)
    assert torch.equal(given[:, :2], previous[:, :2])
    agreement = (given[:, -1, 0].sign() == previous[:, 0, 0]).float().mean().item()
    free_agreement = (free[:, -1, 0].sign() == previous[:, 0, 0]).float().mean().item()
    assert agreement > 0.95, f"given its first two actions the jump continues their mode ({agreement:.2f})"
    assert 0.2 < free_agreement < 0.8, f"with nothing known it keeps both modes ({free_agreement:.2f})"
