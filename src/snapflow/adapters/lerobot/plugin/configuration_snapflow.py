"""The student configs: each declared LeRobot type's config plus ``sampling_mode``, registered with LeRobot's config
registry under ``snapflow_<type>`` as ``SnapFlow<stem>Config`` in this module (where LeRobot's factory looks)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from lerobot.configs.policies import PreTrainedConfig

from snapflow._lazy import resolve
from snapflow.adapters.lerobot_types import LEROBOT_POLICY_TYPES, lerobot_policy_type
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


def student_config_class(base_type: str) -> type[SnapFlowSampling]:
    """The student config class of the declared LeRobot type ``base_type``, made and registered on first use."""
    declared = lerobot_policy_type(base_type)
    name = f"SnapFlow{declared.class_stem}Config"
    if name not in globals():
        namespace = {"__module__": __name__, "__qualname__": name, "__doc__": f"A SnapFlow-distilled {base_type}."}
        made = dataclass(
            type(name, (SnapFlowSampling, resolve(declared.config)), {**namespace, "base_type": base_type})
        )
        globals()[name] = PreTrainedConfig.register_subclass(declared.student_type)(made)
    return globals()[name]


for _declared in LEROBOT_POLICY_TYPES:  # the declared types' classes exist as soon as the plugin is imported
    student_config_class(_declared)


__all__ = ["SnapFlowSampling", "student_config_class"]
