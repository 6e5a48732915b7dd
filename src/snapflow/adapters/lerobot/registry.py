"""Which SnapFlow adapter serves which LeRobot policy, and loading a policy the way LeRobot loads it."""

from __future__ import annotations

from importlib.metadata import version
from typing import Any

from packaging.version import Version
from torch import nn

from snapflow.adapters.hub import check_source
from snapflow.adapters.lerobot.base import LeRobotFlowPolicy
from snapflow.adapters.lerobot.pi0 import PI0FlowPolicy, PI05FlowPolicy
from snapflow.adapters.lerobot.smolvla import SmolVLAFlowPolicy

ADAPTERS: dict[str, type[LeRobotFlowPolicy]] = {
    adapter.policy_type: adapter for adapter in (PI0FlowPolicy, PI05FlowPolicy, SmolVLAFlowPolicy)
}


def adapter_class(policy_type: str) -> type[LeRobotFlowPolicy]:
    """The adapter for a LeRobot policy type, checked against the installed LeRobot."""
    if policy_type not in ADAPTERS:
        raise ValueError(f"snapflow distills LeRobot's {', '.join(sorted(ADAPTERS))} policies, not {policy_type!r}")
    adapter, installed = ADAPTERS[policy_type], version("lerobot")
    if Version(installed) < Version(adapter.minimum_lerobot):
        raise ValueError(
            f"snapflow's {policy_type} adapter needs lerobot >= {adapter.minimum_lerobot} (Python >= 3.12 for "
            f"lerobot >= 0.5); lerobot {installed} is installed"
        )
    return adapter


def base_policy_type(config: Any) -> str:
    """The LeRobot policy type whose adapter serves ``config``: a SnapFlow student's (``snapflow_smolvla``,
    :mod:`snapflow.adapters.lerobot.plugin`) is the type it was distilled from."""
    return getattr(config, "base_type", config.type)


def wrap_policy(policy: nn.Module) -> LeRobotFlowPolicy:
    """The SnapFlow adapter for a LeRobot PI0Policy, PI05Policy or SmolVLAPolicy (phi_s added at zero), or for a
    SnapFlow student of one (its phi_s kept)."""
    return adapter_class(base_policy_type(policy.config))(policy)


def load_pretrained_policy(path: str) -> nn.Module:
    """A LeRobot policy from a hub id or a local pretrained directory, as ``lerobot-eval`` loads it; a mistyped
    folder, an unreachable hub or an unusable repo is named in one line before anything loads."""
    from huggingface_hub.constants import CONFIG_NAME

    check_source(path, CONFIG_NAME, "a LeRobot policy")  # before LeRobot's loaders import (seconds)
    from lerobot.configs.policies import PreTrainedConfig
    from lerobot.policies.factory import get_policy_class

    from snapflow.adapters.lerobot.plugin import STUDENT_POLICIES, SnapFlowSampling  # registers the student types

    config = PreTrainedConfig.from_pretrained(path)
    adapter_class(base_policy_type(config))
    if isinstance(config, SnapFlowSampling):  # LeRobot < 0.5 resolves only its own types
        return STUDENT_POLICIES[config.base_type].from_pretrained(path)
    return get_policy_class(config.type).from_pretrained(path)


__all__ = ["ADAPTERS", "adapter_class", "base_policy_type", "wrap_policy", "load_pretrained_policy"]
