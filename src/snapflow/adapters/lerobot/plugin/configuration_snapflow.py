"""The student configs: LeRobot's SmolVLA / pi0 / pi0.5 config plus ``sampling_mode``, registered with LeRobot's
config registry under ``snapflow_<type>``."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from lerobot.configs.policies import PreTrainedConfig
from lerobot.policies.pi0.configuration_pi0 import PI0Config
from lerobot.policies.pi05.configuration_pi05 import PI05Config
from lerobot.policies.smolvla.configuration_smolvla import SmolVLAConfig

from snapflow.flow.modes import SNAPFLOW_1, SamplingMode


@dataclass
class SnapFlowSampling:
    """What a student's config adds to its LeRobot config: how LeRobot's ``select_action`` /
    ``predict_action_chunk`` sample, ``snapflow-N`` (one jump by default) or ``teacher-N`` (the same checkpoint
    as its flow-matching teacher)."""

    #: the LeRobot policy type the student was distilled from
    base_type: ClassVar[str]
    sampling_mode: str = SNAPFLOW_1.name

    def __post_init__(self) -> None:
        super().__post_init__()  # the LeRobot config's own checks
        SamplingMode.parse(self.sampling_mode)  # a named error for an unknown mode, at load time

    @property
    def mode(self) -> SamplingMode:
        return SamplingMode.parse(self.sampling_mode)


@PreTrainedConfig.register_subclass("snapflow_smolvla")
@dataclass
class SnapFlowSmolVLAConfig(SnapFlowSampling, SmolVLAConfig):
    """A SnapFlow-distilled SmolVLA."""

    base_type: ClassVar[str] = "smolvla"


@PreTrainedConfig.register_subclass("snapflow_pi0")
@dataclass
class SnapFlowPI0Config(SnapFlowSampling, PI0Config):
    """A SnapFlow-distilled pi0."""

    base_type: ClassVar[str] = "pi0"


@PreTrainedConfig.register_subclass("snapflow_pi05")
@dataclass
class SnapFlowPI05Config(SnapFlowSampling, PI05Config):
    """A SnapFlow-distilled pi0.5."""

    base_type: ClassVar[str] = "pi05"


__all__ = ["SnapFlowSampling", "SnapFlowSmolVLAConfig", "SnapFlowPI0Config", "SnapFlowPI05Config"]
