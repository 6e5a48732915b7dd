"""The target-time embedding: exact features, zero-initialised output layer, bit-identical wrapping."""

from __future__ import annotations

import copy
import math

import pytest
import torch

from snapflow.flow import UniformTimeSampler
from snapflow.nn import SnapFlowPolicy, TargetTimeEmbedding, sinusoidal_features
from snapflow.objective import SnapFlowObjective
from tests.helpers import ACTION_DIM, CHUNK, OBSERVATION_DIM, make_model


def test_sinusoidal_features_by_hand():
    """Features are sin then cos of 2 pi t / p for geometrically spaced periods p; an odd width is refused."""
    t = torch.tensor([0.0, 0.3, 1.0])
    features = sinusoidal_features(t, 4, min_period=0.5, max_period=2.0)
    # two periods, 0.5 and 2.0: [sin(2 pi t / .5), sin(2 pi t / 2), cos(2 pi t / .5), cos(2 pi t / 2)]
    for row, value in enumerate(t.tolist()):
        expected = [
            math.sin(4 * math.pi * value),
            math.sin(math.pi * value),
            math.cos(4 * math.pi * value),
            math.cos(math.pi * value),
        ]
        assert features[row].tolist() == pytest.approx(expected, abs=1e-6)
    with pytest.raises(ValueError, match="even"):
        sinusoidal_features(t, 5)
    with pytest.raises(ValueError, match=r"time must have shape \(B,\)"):
        sinusoidal_features(t[:, None], 4)


def test_only_the_output_layer_starts_at_zero():
    """phi_s is zero at init through its output layer only, so its input layer can still learn."""
    embedding = TargetTimeEmbedding(16)
    assert torch.count_nonzero(embedding.linear_out.weight) == 0
    assert torch.count_nonzero(embedding.linear_out.bias) == 0
    assert torch.count_nonzero(embedding.linear_in.weight) > 0
    assert torch.equal(embedding(torch.rand(5)), torch.zeros(5, 16))


def test_the_input_layer_is_the_same_at_every_wrapping_and_leaves_the_global_random_stream_alone():
    """phi_s's input layer is drawn from a fixed seed with the global random state restored after: a teacher wrapped
    twice gets the same weights (an opened LeRobot teacher digests the same), and later global draws do not shift."""
    torch.manual_seed(1)
    first = TargetTimeEmbedding(16)
    after_first = torch.rand(3)
    torch.manual_seed(2)
    second = TargetTimeEmbedding(16)
    torch.manual_seed(1)
    assert torch.equal(torch.rand(3), after_first), "the global stream did not move"
    for name, value in first.state_dict().items():
        assert torch.equal(value, second.state_dict()[name]), name
    bound = 1 / math.sqrt(first.sinusoid_dim)  # nn.Linear's own init range
    assert first.linear_in.weight.abs().max() <= bound and first.linear_in.weight.std() > bound / 3


def test_wrapping_changes_no_output_bit_at_init():
    """A freshly wrapped student is the teacher bit for bit, whatever target time it is asked for."""
    model = make_model()
    teacher = SnapFlowPolicy(copy.deepcopy(model), target_time=False)
    student = SnapFlowPolicy(copy.deepcopy(model))
    generator = torch.Generator().manual_seed(0)
    observation = torch.randn(8, OBSERVATION_DIM, generator=generator)
    x = torch.randn(8, CHUNK, ACTION_DIM, generator=generator)
    for t_value in (1.0, 0.75, 0.5, 0.1, 0.0):
        t = torch.full((8,), t_value)
        s = torch.rand(8, generator=generator) * t_value
        expected = teacher.velocity(x, t, t, teacher.encode(observation))
        for target in (s, t, torch.zeros(8)):
            assert torch.equal(student.velocity(x, t, target, student.encode(observation)), expected)


def test_wrapper_rejects_models_without_the_protocol():
    """Missing protocol methods, and a missing integer time_embedding_dim, are named."""
    with pytest.raises(TypeError, match="embed_time"):
        SnapFlowPolicy(torch.nn.Linear(2, 2))
    model = make_model()
    model.time_embedding_dim = 16.0
    with pytest.raises(TypeError, match="integer time_embedding_dim"):
        SnapFlowPolicy(model)


def test_expert_parameters_are_all_but_the_prefix_and_include_phi_s():
    """Distillation trains everything but the model's prefix_parameters(): phi_s included, the encoder left out."""
    student = SnapFlowPolicy(make_model())
    prefix = {id(parameter) for parameter in student.model.prefix_parameters()}
    expert = {id(parameter) for parameter in student.expert_parameters()}
    assert prefix == {id(parameter) for parameter in student.model.observation_encoder.parameters()}
    assert expert == {id(parameter) for parameter in student.parameters()} - prefix
    assert {id(parameter) for parameter in student.target_time_embedding.parameters()} <= expert
    # a model without a prefix trains whole
    model = make_model()
    model.prefix_parameters = None
    whole = SnapFlowPolicy(model, target_time=False)
    assert [id(p) for p in whole.expert_parameters()] == [id(p) for p in whole.parameters()]


def _distillation_problem() -> tuple[SnapFlowPolicy, tuple[torch.Tensor, ...], torch.Generator]:
    """A fresh student and one batch (observation, actions, x_1) to distil it on."""
    torch.manual_seed(0)
    student = SnapFlowPolicy(make_model())
    generator = torch.Generator().manual_seed(1)
    observation = torch.randn(16, OBSERVATION_DIM, generator=generator)
    actions = torch.randn(16, CHUNK, ACTION_DIM, generator=generator)
    return student, (observation, actions, torch.randn(16, CHUNK, ACTION_DIM, generator=generator)), generator


def _distil(
    student: SnapFlowPolicy, observation: torch.Tensor, actions: torch.Tensor, generator: torch.Generator, steps: int
) -> set[str]:
    """``steps`` Adam steps of the SnapFlow loss; returns the names of the phi_s tensors that moved."""
    initial = copy.deepcopy(student.target_time_embedding.state_dict())
    objective = SnapFlowObjective(time_sampler=UniformTimeSampler())
    optimizer = torch.optim.Adam(student.parameters(), lr=1e-2)
    for _ in range(steps):
        optimizer.zero_grad()
        objective(student, observation, actions, generator=generator).loss.backward()
        optimizer.step()
    current = student.target_time_embedding.state_dict()
    return {name for name, before in initial.items() if not torch.equal(before, current[name])}


def test_phi_s_input_layer_learns_from_the_second_step_on():
    """A first step moves only phi_s's zero output layer (no gradient reaches its input layer through zero weights);
    the second moves both layers, which a zero input layer never would (SiLU(0) = 0)."""
    student, (observation, actions, _), generator = _distillation_problem()
    assert _distil(student, observation, actions, generator, steps=1) == {"linear_out.weight", "linear_out.bias"}
    assert _distil(student, observation, actions, generator, steps=1) == set(student.target_time_embedding.state_dict())


@pytest.mark.slow
def test_distillation_moves_both_layers_and_makes_the_output_depend_on_s():
    """Learning test: 20 distillation steps move every phi_s tensor and make the one-step jump F(x, 1, s=0) differ
    from the instantaneous velocity F(x, 1, s=1), which it equals at init."""
    student, (observation, actions, x), generator = _distillation_problem()
    one, zero = torch.ones(16), torch.zeros(16)

    def jump_minus_local() -> torch.Tensor:
        context = student.encode(observation)
        return student.velocity(x, one, zero, context) - student.velocity(x, one, one, context)

    assert torch.count_nonzero(jump_minus_local()) == 0
    moved = _distil(student, observation, actions, generator, steps=20)
    assert moved == set(student.target_time_embedding.state_dict())
    assert jump_minus_local().abs().max() > 1e-3
