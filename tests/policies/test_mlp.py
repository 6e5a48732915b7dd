"""The MLP policy: its processor (normalised state + one-hot instruction) by hand, and its model's named errors."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from snapflow.policies.mlp import MLPFlowModel, MLPPolicyConfig, MLPProcessor
from snapflow.policies.normalization import NormalizationStats
from snapflow.protocol import TimeEmbeddingModel

INSTRUCTIONS = ["reach the goal", "push the puck", "open the door"]
CONFIG = MLPPolicyConfig(
    observation_dim=4 + len(INSTRUCTIONS), action_dim=2, chunk_length=3, hidden_dim=16, time_embedding_dim=8
)
STATS = NormalizationStats([1.0, -2.0, 0.5, 0.0], [2.0, 4.0, 0.5, 1.0], [0.1, -0.1], [0.5, 2.0])


def test_observation_is_the_normalised_state_then_a_one_hot_of_the_instruction_by_hand():
    """The leading state entries go through (s - mean) / std, the rest of the state is ignored, and the instruction
    becomes a one-hot in the order of the training instructions."""
    processor = MLPProcessor(CONFIG, STATS, INSTRUCTIONS)
    assert processor.state_dim == 4
    states = np.array([[3.0, 2.0, 1.0, 5.0, 99.0], [1.0, -2.0, 0.0, -1.0, -99.0]], dtype=np.float32)
    observation = processor.observation(states, ["open the door", "reach the goal"])
    expected = torch.tensor([[1.0, 1.0, 1.0, 5.0, 0.0, 0.0, 1.0], [0.0, 0.0, -1.0, -1.0, 1.0, 0.0, 0.0]])
    assert torch.equal(observation, expected)
    actions = torch.tensor([[[0.6, 3.9]]])
    assert torch.allclose(processor.normalize_actions(actions), torch.tensor([[[1.0, 2.0]]]))
    assert torch.allclose(processor.unnormalize_actions(processor.normalize_actions(actions)), actions)


def test_unknown_instruction_and_bad_dimensions_are_named():
    """An instruction the policy was not trained on, too few state entries, no room for a state entry, and statistics
    of the wrong size are ValueErrors naming the problem."""
    processor = MLPProcessor(CONFIG, STATS, INSTRUCTIONS)
    with pytest.raises(
        ValueError,
        match=r"trained on the instructions \['reach the goal', 'push the puck', 'open the "
        r"door'\]; it cannot read \['close the window'\]",
    ):
        processor.observation(np.zeros((2, 4)), ["push the puck", "close the window"])
    with pytest.raises(ValueError, match=r"states must have shape \(batch, >= 4\), got \(2, 3\)"):
        processor.observation(np.zeros((2, 3)), ["push the puck"] * 2)
    with pytest.raises(ValueError, match="observation_dim 3 leaves no state entry"):
        MLPProcessor(MLPPolicyConfig(observation_dim=3, action_dim=2), STATS, INSTRUCTIONS)
    with pytest.raises(ValueError, match="one-hot of 0 instruction"):
        MLPProcessor(CONFIG, STATS, [])
    with pytest.raises(ValueError, match="normalisation stats have 4 state dimensions, the policy expects 5"):
        MLPProcessor(CONFIG, STATS, INSTRUCTIONS[:2])
    with pytest.raises(ValueError, match="normalisation stats have 2 action dimensions, the policy expects 3"):
        MLPProcessor(MLPPolicyConfig(observation_dim=7, action_dim=3), STATS, INSTRUCTIONS)


def test_model_speaks_the_protocol_and_names_bad_shapes():
    """The MLP implements TimeEmbeddingModel, its prefix is the observation encoder, and wrong input shapes are
    refused with the shape expected."""
    model = MLPFlowModel(CONFIG)
    assert isinstance(model, TimeEmbeddingModel) and model.time_embedding_dim == 8
    assert [id(p) for p in model.prefix_parameters()] == [id(p) for p in model.observation_encoder.parameters()]
    context = model.encode(torch.zeros(2, 7))
    velocity = model.velocity_from_time_embedding(torch.zeros(2, 3, 2), model.embed_time(torch.rand(2)), context)
    assert velocity.shape == (2, 3, 2)
    with pytest.raises(ValueError, match=r"observation must have shape \(B, 7\), got \(2, 6\)"):
        model.encode(torch.zeros(2, 6))
    with pytest.raises(ValueError, match=r"noisy actions must have shape \(B, 3, 2\), got \(2, 2, 3\)"):
        model.velocity_from_time_embedding(torch.zeros(2, 2, 3), model.embed_time(torch.rand(2)), context)
