"""The target-time embedding: exact features, zero-initialised output layer, bit-identical wrapping."""

from __future__ import annotations

import copy
import math

import pytest
import torch

from snapflow import SnapFlowObjective, SnapFlowPolicy, UniformTimeSampler
from snapflow.nn import TargetTimeEmbedding, sinusoidal_features
from tests.helpers import make_model


def test_sinusoidal_features_by_hand():
    t = torch.tensor([0.0, 0.3, 1.0])
    features = sinusoidal_features(t, 4, min_period=0.5, max_period=2.0)
    # two periods, 0.5 and 2.0: [sin(2 pi t / .5), sin(2 pi t / 2), cos(2 pi t / .5), cos(2 pi t / 2)]
    for row, value in enumerate(t.tolist()):
        expected = [math.sin(4 * math.pi * value), math.sin(math.pi * value), math.cos(4 * math.pi * value), math.cos(math.pi * value)]
        assert features[row].tolist() == pytest.approx(expected, abs=1e-6)
    with pytest.raises(ValueError, match="even"):
        sinusoidal_features(t, 5)


def test_only_the_output_layer_starts_at_zero():
    embedding = TargetTimeEmbedding(16)
    assert torch.count_nonzero(embedding.linear_out.weight) == 0
    assert torch.count_nonzero(embedding.linear_out.bias) == 0
    assert torch.count_nonzero(embedding.linear_in.weight) > 0
    assert torch.equal(embedding(torch.rand(5)), torch.zeros(5, 16))


def test_wrapping_changes_no_output_bit_at_init():
    model = make_model()
    teacher = SnapFlowPolicy(copy.deepcopy(model), target_time=False)
    student = SnapFlowPolicy(copy.deepcopy(model))
    generator = torch.Generator().manual_seed(0)
    observation = torch.randn(8, 5, generator=generator)
    x = torch.randn(8, 3, 2, generator=generator)
    for t_value in (1.0, 0.75, 0.5, 0.1, 0.0):
        t = torch.full((8,), t_value)
        s = torch.rand(8, generator=generator) * t_value
        expected = teacher.velocity(x, t, t, teacher.encode(observation))
        for target in (s, t, torch.zeros(8)):
            assert torch.equal(student.velocity(x, t, target, student.encode(observation)), expected)


def test_wrapper_rejects_models_without_the_protocol():
    with pytest.raises(TypeError, match="embed_time"):
        SnapFlowPolicy(torch.nn.Linear(2, 2))


def test_distillation_moves_both_layers_and_makes_the_output_depend_on_s():
    torch.manual_seed(0)
    student = SnapFlowPolicy(make_model())
    initial = copy.deepcopy(student.target_time_embedding.state_dict())
    generator = torch.Generator().manual_seed(1)
    observation, actions = torch.randn(16, 5, generator=generator), torch.randn(16, 3, 2, generator=generator)
    x, one, zero = torch.randn(16, 3, 2, generator=generator), torch.ones(16), torch.zeros(16)

    def jump_minus_local():
        context = student.encode(observation)
        return student.velocity(x, one, zero, context) - student.velocity(x, one, one, context)

    assert torch.count_nonzero(jump_minus_local()) == 0
    objective = SnapFlowObjective(time_sampler=UniformTimeSampler())
    optimizer = torch.optim.Adam(student.parameters(), lr=1e-2)
    for _ in range(20):
        optimizer.zero_grad()
        objective(student, observation, actions, generator=generator).loss.backward()
        optimizer.step()
    for name, before in initial.items():
        after = student.target_time_embedding.state_dict()[name]
        assert not torch.equal(before, after), f"{name} did not move"
    assert jump_minus_local().abs().max() > 1e-3
