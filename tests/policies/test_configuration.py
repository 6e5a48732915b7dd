"""Policy configurations: typed fields (a flag is not a size), their checks, and the JSON round trip."""

from __future__ import annotations

import dataclasses

import pytest

from snapflow.policies.configuration import PolicyConfig
from snapflow.policies.minivla import MiniVLAConfig
from snapflow.policies.mlp import MLPPolicyConfig

CONFIGS = {
    "mlp": (MLPPolicyConfig, {"observation_dim": 7, "action_dim": 2}),
    "minivla": (MiniVLAConfig, {}),
}


@pytest.fixture(params=list(CONFIGS))
def config_class_and_required(request: pytest.FixtureRequest) -> tuple[type[PolicyConfig], dict]:
    return CONFIGS[request.param]


@pytest.mark.parametrize(
    "field, value, message",
    [
        ("action_dim", True, "action_dim must be int, got True"),
        ("chunk_length", 2.0, "chunk_length must be int, got 2.0"),
        ("chunk_length", "8", "chunk_length must be int, got '8'"),
        ("action_dim", 0, "action_dim must be at least 1, got 0"),
    ],
)
def test_ints_refuse_bools_floats_strings_and_non_positive_values(config_class_and_required, field, value, message):
    """Every int field of both configurations refuses a bool (a flag given for a size), a float, a string and
    values below 1, naming the configuration and the field."""
    config_class, required = config_class_and_required
    with pytest.raises(ValueError, match=f"{config_class.__name__}.{message}"):
        config_class(**{**required, field: value})


def test_a_bool_refuses_an_int():
    """MiniVLA's use_image flag is a bool; 1 is refused rather than read as True."""
    with pytest.raises(ValueError, match="MiniVLAConfig.use_image must be bool, got 1"):
        MiniVLAConfig(use_image=1)


def test_each_configuration_adds_its_own_checks():
    """The MLP's time embedding must be even; MiniVLA's image must tile into patches."""
    with pytest.raises(ValueError, match="MLPPolicyConfig.time_embedding_dim must be even, got 9"):
        MLPPolicyConfig(observation_dim=7, action_dim=2, time_embedding_dim=9)
    with pytest.raises(ValueError, match=r"image_size \(40\) must be a multiple of patch_size \(16\)"):
        MiniVLAConfig(use_image=True, image_size=40)


def test_json_round_trip_and_unknown_fields(config_class_and_required):
    """to_dict / from_dict give the configuration back; an unknown field is named; a configuration is frozen."""
    config_class, required = config_class_and_required
    config = config_class(**required, chunk_length=5)
    assert config_class.from_dict(config.to_dict()) == config
    with pytest.raises(ValueError, match=rf"unknown {config_class.__name__} field\(s\) \['widht'\]"):
        config_class.from_dict({**config.to_dict(), "widht": 3})
    with pytest.raises(dataclasses.FrozenInstanceError):
        config.chunk_length = 6
