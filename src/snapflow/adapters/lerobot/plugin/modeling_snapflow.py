"""The student policies: LeRobot's policy class with phi_s attached when built (so LeRobot's ``from_pretrained``
finds it in the model), every tensor loaded strictly, and LeRobot's action API sampling with the config's
``sampling_mode``."""

from __future__ import annotations

from typing import Any

from lerobot.policies.pi0.modeling_pi0 import PI0Policy
from lerobot.policies.pi05.modeling_pi05 import PI05Policy
from lerobot.policies.smolvla.modeling_smolvla import SmolVLAPolicy

from snapflow.adapters.lerobot.plugin.configuration_snapflow import (
    SnapFlowPI0Config,
    SnapFlowPI05Config,
    SnapFlowSmolVLAConfig,
)
from snapflow.adapters.lerobot.registry import adapter_class


class SnapFlowStudent:
    """Mixed in before a LeRobot policy class."""

    def __init__(self, config: Any, **kwargs: Any) -> None:
        super().__init__(config, **kwargs)
        adapter_class(config.base_type)(self).use_sampling_mode(config.mode)

    @classmethod
    def _load_as_safetensor(cls, model: Any, model_file: str, map_location: str, strict: bool) -> Any:
        # LeRobot loads SmolVLA non-strictly: a missing phi_s would leave it at zero, the naive step under
        # SnapFlow's name
        return super()._load_as_safetensor(model, model_file, map_location, True)


class SnapFlowSmolVLAPolicy(SnapFlowStudent, SmolVLAPolicy):
    config_class = SnapFlowSmolVLAConfig
    name = "snapflow_smolvla"


class SnapFlowPI0Policy(SnapFlowStudent, PI0Policy):
    config_class = SnapFlowPI0Config
    name = "snapflow_pi0"


class SnapFlowPI05Policy(SnapFlowStudent, PI05Policy):
    config_class = SnapFlowPI05Config
    name = "snapflow_pi05"


__all__ = ["SnapFlowStudent", "SnapFlowSmolVLAPolicy", "SnapFlowPI0Policy", "SnapFlowPI05Policy"]
