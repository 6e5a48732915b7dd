"""The registry of built-in policies: a name -> its configuration, model and processor classes.

Checkpoints record the name; data, training, evaluation and benchmarks build policies only through here, so a
new built-in policy is a folder ``policies/<name>/`` (configuration, modeling, processor) and one
:func:`register_policy` call below.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, fields
from typing import TYPE_CHECKING, Any

from snapflow._lazy import resolve
from snapflow.errors import InvalidInputError
from snapflow.policies.configuration import PolicyConfig
from snapflow.policies.minivla.configuration import MiniVLAConfig
from snapflow.policies.mlp.configuration import MLPPolicyConfig

if TYPE_CHECKING:
    from torch import nn

    from snapflow.policies.normalization import NormalizationStats
    from snapflow.policies.processor import Processor


@dataclass(frozen=True)
class PolicyType:
    """One built-in policy: ``model_class(config)`` implements :class:`snapflow.protocol.TimeEmbeddingModel`.

    The model and processor may be given as ``"module:Class"``, imported when first used, so that listing the
    policies and reading their configurations (the CLI's choices and defaults) loads no torch."""

    name: str
    config_class: type[PolicyConfig]
    model: type | str
    processor: type | str

    @property
    def model_class(self) -> type[nn.Module]:
        return resolve(self.model)

    @property
    def processor_class(self) -> type[Processor]:
        return resolve(self.processor)


POLICIES: dict[str, PolicyType] = {}


def register_policy(name: str, config_class: type[PolicyConfig], model: type | str, processor: type | str) -> None:
    """Add policy ``name``: its configuration class, and its model and processor classes (or ``"module:Class"``)."""
    if name in POLICIES:
        raise ValueError(f"a policy named {name!r} is registered already")
    POLICIES[name] = PolicyType(name, config_class, model, processor)


register_policy(
    "minivla",
    MiniVLAConfig,
    "snapflow.policies.minivla.modeling:MiniVLA",
    "snapflow.policies.minivla.processor:MiniVLAProcessor",
)
register_policy(
    "mlp",
    MLPPolicyConfig,
    "snapflow.policies.mlp.modeling:MLPFlowModel",
    "snapflow.policies.mlp.processor:MLPProcessor",
)


def policy_type(name: str) -> PolicyType:
    """The registered policy ``name``, or a ValueError listing the known ones."""
    if name not in POLICIES:
        raise InvalidInputError(f"unknown policy {name!r}; the built-in policies are {', '.join(POLICIES)}")
    return POLICIES[name]


def policy_type_of(config: PolicyConfig) -> PolicyType:
    """The registered policy whose configuration ``config`` is."""
    for entry in POLICIES.values():
        if type(config) is entry.config_class:
            return entry
    raise ValueError(f"{type(config).__name__} is not the configuration of a registered policy")


def default_config(
    name: str, state_dim: int, action_dim: int, instructions: Sequence[str], **overrides: Any
) -> PolicyConfig:
    """Policy ``name`` configured for data of these dimensions and instructions, with ``overrides`` applied."""
    entry = policy_type(name)
    unknown = sorted(set(overrides) - {field.name for field in fields(entry.config_class)})
    if unknown:
        raise InvalidInputError(f"the {name} policy has no option {', '.join(unknown)}")
    return entry.processor_class.default_config(state_dim, action_dim, instructions, **overrides)


def make_model(config: PolicyConfig) -> nn.Module:
    return policy_type_of(config).model_class(config)


def make_processor(config: PolicyConfig, stats: NormalizationStats, instructions: Sequence[str] = ()) -> Processor:
    return policy_type_of(config).processor_class(config, stats, instructions)


def fit_processor(config: PolicyConfig, demonstrations: Any, episodes: list[int]) -> Processor:
    """The processor of ``config`` with the statistics of the given demonstration episodes."""
    return policy_type_of(config).processor_class.fit(config, demonstrations, episodes)


__all__ = [
    "POLICIES",
    "PolicyType",
    "register_policy",
    "policy_type",
    "policy_type_of",
    "default_config",
    "make_model",
    "make_processor",
    "fit_processor",
]
