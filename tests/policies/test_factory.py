"""The policy registry: lookup by name, configurations for a benchmark's dimensions, and named errors."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest

from snapflow.data import Demonstrations, Episode
from snapflow.envs.metaworld import ACTION_DIM, MT10_INSTRUCTIONS, STATE_DIM
from snapflow.policies.configuration import PolicyConfig
from snapflow.policies.factory import (
    POLICIES,
    default_config,
    fit_processor,
    make_model,
    make_processor,
    policy_type,
    policy_type_of,
    register_policy,
)
from snapflow.policies.minivla import MiniVLA, MiniVLAConfig, MiniVLAProcessor
from snapflow.policies.mlp import MLPFlowModel, MLPPolicyConfig, MLPProcessor
from snapflow.policies.normalization import NormalizationStats
from snapflow.protocol import TimeEmbeddingModel

MT10 = list(MT10_INSTRUCTIONS.values())


def test_registry_lookup_by_name_and_by_configuration():
    """Each built-in policy is found by its name and by the type of its configuration."""
    assert set(POLICIES) == {"minivla", "mlp"}
    for name, config, model, processor in (
        ("minivla", MiniVLAConfig, MiniVLA, MiniVLAProcessor),
        ("mlp", MLPPolicyConfig, MLPFlowModel, MLPProcessor),
    ):
        entry = policy_type(name)
        assert (entry.name, entry.config_class, entry.model_class, entry.processor_class) == (
            name,
            config,
            model,
            processor,
        )
    assert policy_type_of(MiniVLAConfig()) is POLICIES["minivla"]
    assert policy_type_of(MLPPolicyConfig(observation_dim=3, action_dim=2)) is POLICIES["mlp"]


def test_unknown_policy_duplicate_name_and_foreign_configuration_are_named():
    """An unknown name lists the built-in ones; a name cannot be registered twice; a configuration no policy
    registered is refused by name."""

    @dataclass(frozen=True)
    class ForeignConfig(PolicyConfig):
        action_dim: int = 2

    with pytest.raises(ValueError, match="unknown policy 'gpt'; the built-in policies are minivla, mlp"):
        policy_type("gpt")
    with pytest.raises(ValueError, match="a policy named 'mlp' is registered already"):
        register_policy("mlp", MLPPolicyConfig, MLPFlowModel, MLPProcessor)
    assert set(POLICIES) == {"minivla", "mlp"}
    with pytest.raises(ValueError, match="ForeignConfig is not the configuration of a registered policy"):
        make_model(ForeignConfig())


def test_default_configs_on_mt10_dimensions():
    """On MT10 (39-d state, 4-d actions, 10 instructions) the MLP reads the whole state plus a 10-way one-hot and
    MiniVLA the whole state; both write 4-d actions in chunks of 8."""
    mlp = default_config("mlp", STATE_DIM, ACTION_DIM, MT10)
    assert mlp == MLPPolicyConfig(observation_dim=49, action_dim=4, chunk_length=8, hidden_dim=512)
    assert MLPProcessor.state_entries(mlp, MT10) == STATE_DIM
    minivla = default_config("minivla", STATE_DIM, ACTION_DIM, MT10)
    assert minivla == MiniVLAConfig(state_dim=39, action_dim=4) and minivla.chunk_length == 8
    assert MiniVLAProcessor.state_entries(minivla, MT10) == STATE_DIM
    assert default_config("mlp", STATE_DIM, ACTION_DIM, MT10, hidden_dim=64, chunk_length=4).hidden_dim == 64
    assert default_config("minivla", 4, ACTION_DIM, MT10, use_image=True).use_image


@pytest.mark.parametrize(
    "name, overrides, message",
    [
        ("mlp", {"prefix_width": 8}, "the mlp policy has no option prefix_width"),
        (
            "minivla",
            {"observation_dim": 3, "hidden_dim": 8},
            "the minivla policy has no option hidden_dim, observation_dim",
        ),
        ("mlp", {"hidden_dim": True}, "MLPPolicyConfig.hidden_dim must be int, got True"),
        ("gpt", {}, "unknown policy 'gpt'"),
    ],
)
def test_default_config_names_a_bad_override(name: str, overrides: dict, message: str):
    """An option the policy lacks, or a value of the wrong type, is named."""
    with pytest.raises(ValueError, match=message):
        default_config(name, STATE_DIM, ACTION_DIM, MT10, **overrides)


def test_models_and_processors_are_built_from_the_configuration():
    """make_model and make_processor dispatch on the configuration; every model speaks TimeEmbeddingModel."""
    stats = NormalizationStats([0.0] * 3, [1.0] * 3, [0.0] * 2, [1.0] * 2)
    for config in (
        MiniVLAConfig(
            state_dim=3, action_dim=2, prefix_width=16, expert_width=16, num_layers=1, num_heads=2, head_dim=8
        ),
        MLPPolicyConfig(observation_dim=5, action_dim=2, hidden_dim=16),
    ):
        entry = policy_type_of(config)
        model = make_model(config)
        assert type(model) is entry.model_class and isinstance(model, TimeEmbeddingModel)
        processor = make_processor(config, stats, ["reach", "push"])
        assert type(processor) is entry.processor_class
        assert processor.config is config and processor.instructions == ("reach", "push") and processor.state_dim == 3


def test_fit_processor_takes_the_statistics_of_the_chosen_episodes():
    """Statistics come from the given episodes' rows only, over the state entries the policy reads; the instructions
    are all of the demonstrations', in order."""
    generator = np.random.default_rng(0)
    states, actions = generator.normal(size=(9, 6)).astype(np.float32), generator.normal(size=(9, 2)).astype(np.float32)
    episodes = [Episode("reach-v3", 0, 0, 3), Episode("push-v3", 0, 3, 4), Episode("reach-v3", 1, 7, 2)]
    demonstrations = Demonstrations(
        states, actions, np.repeat([0, 1, 2], [3, 4, 2]), episodes, {"reach-v3": "reach", "push-v3": "push"}
    )
    rows = [0, 1, 2, 7, 8]
    for config, entries in (
        (MLPPolicyConfig(observation_dim=6, action_dim=2), 4),
        (MiniVLAConfig(state_dim=5, action_dim=2), 5),
    ):
        processor = fit_processor(config, demonstrations, [0, 2])
        assert processor.instructions == ("reach", "push") and processor.state_dim == entries
        assert np.allclose(processor.stats.state_mean, states[rows, :entries].mean(0))
        assert np.allclose(processor.stats.state_std, states[rows, :entries].std(0))
        assert np.allclose(processor.stats.action_mean, actions[rows].mean(0))
        assert np.allclose(processor.stats.action_std, actions[rows].std(0))
