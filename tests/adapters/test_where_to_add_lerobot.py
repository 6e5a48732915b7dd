"""docs/ARCHITECTURE.md's "where to add" a LeRobot policy type, done in this test alone: an adapter (a subclass of
``LeRobotFlowPolicy``, here SmolVLA's under a new type) and one ``register_lerobot_policy_type`` declaration. The
registry, the student type LeRobot's tools load, its distillation folder and ``snapflow bench --architecture`` then
follow with no other edit."""

from __future__ import annotations

import argparse
from dataclasses import asdict

import pytest
import torch

pytest.importorskip("lerobot", reason="LeRobot is installed by the README's test command; this environment lacks it")

from lerobot.configs.policies import PreTrainedConfig  # noqa: E402
from lerobot.policies.smolvla.configuration_smolvla import SmolVLAConfig  # noqa: E402
from lerobot.policies.smolvla.modeling_smolvla import SmolVLAPolicy  # noqa: E402

from snapflow.adapters.lerobot import load_distilled, save_distilled, wrap_policy  # noqa: E402
from snapflow.adapters.lerobot.plugin import (  # noqa: E402
    configuration_snapflow,
    modeling_snapflow,
    processor_snapflow,
    student_policy,
)
from snapflow.adapters.lerobot.registry import adapter_class  # noqa: E402
from snapflow.adapters.lerobot.smolvla import SmolVLAFlowPolicy  # noqa: E402
from snapflow.adapters.lerobot_types import (  # noqa: E402
    LEROBOT_POLICY_TYPES,
    LeRobotPolicyType,
    lerobot_loads_plugins,
    register_lerobot_policy_type,
)
from snapflow.benchmark.architectures import architectures  # noqa: E402
from snapflow.cli import build_parser  # noqa: E402
from tests.lerobot_tiny import build_tiny_smolvla, randomise_target_time  # noqa: E402

NAME = "throwaway_vla"


@PreTrainedConfig.register_subclass(NAME)
class ThrowawayConfig(SmolVLAConfig):
    """LeRobot's side, as a new LeRobot policy brings it: a config type of its own."""


class ThrowawayPolicy(SmolVLAPolicy):
    config_class = ThrowawayConfig
    name = NAME


class ThrowawayFlowPolicy(SmolVLAFlowPolicy):
    """Step 1: the adapter (SmolVLA's internals under the new type)."""

    policy_type = NAME


@pytest.fixture
def declared():
    """Step 2: the one declaration; undone afterwards, with what the plugin made from it."""
    register_lerobot_policy_type(
        LeRobotPolicyType(
            NAME,
            "ThrowawayVLA",
            f"{__name__}:ThrowawayConfig",
            f"{__name__}:ThrowawayPolicy",
            f"{__name__}:ThrowawayFlowPolicy",
            architecture_options={"load_vlm_weights": False},
            vlm_option="vlm_model_name",
        )
    )
    yield LEROBOT_POLICY_TYPES[NAME]
    del LEROBOT_POLICY_TYPES[NAME]
    for module, made in (
        (configuration_snapflow, "SnapFlowThrowawayVLAConfig"),
        (modeling_snapflow, "SnapFlowThrowawayVLAPolicy"),
        (processor_snapflow, f"make_snapflow_{NAME}_pre_post_processors"),
    ):
        vars(module).pop(made, None)


def test_a_lerobot_policy_type_is_an_adapter_and_one_declaration(declared, vlm_directory, tmp_path):
    assert adapter_class(NAME) is ThrowawayFlowPolicy
    assert NAME in architectures()
    commands = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction)).choices
    assert NAME in next(a for a in commands["bench"]._actions if a.dest == "architecture").choices
    assert NAME in next(a for a in commands["distill"]._actions if a.dest == "policy").help, "no hand-written list"

    tiny = build_tiny_smolvla(vlm_directory)
    policy = ThrowawayPolicy(ThrowawayConfig(**{key: value for key, value in asdict(tiny.config).items()}))
    policy.load_state_dict(tiny.state_dict())
    adapter = wrap_policy(policy)
    assert type(adapter) is ThrowawayFlowPolicy

    folder = save_distilled(randomise_target_time(adapter), tmp_path / "student")
    loaded = load_distilled(folder)
    assert type(loaded.policy) is student_policy(NAME) and loaded.policy.config.type == declared.student_type
    assert isinstance(loaded.policy, ThrowawayPolicy) and loaded.policy.config.base_type == NAME
    saved, back = (p.model.target_time_embedding.state_dict() for p in (adapter.policy, loaded.policy))
    assert all(torch.equal(saved[key], back[key]) for key in saved), "phi_s came back"
    if lerobot_loads_plugins():  # LeRobot's factory finds third-party types
        from lerobot.policies.factory import get_policy_class

        assert get_policy_class(declared.student_type) is student_policy(NAME)
