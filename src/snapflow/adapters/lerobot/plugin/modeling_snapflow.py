"""The student policies: each declared LeRobot type's policy class with phi_s attached when built (so LeRobot's
``from_pretrained`` finds it in the model), every tensor loaded strictly, and LeRobot's action API sampling with the
config's ``sampling_mode``; ``SnapFlow<stem>Policy`` in this module, where LeRobot's factory looks."""

from __future__ import annotations

from typing import Any

from snapflow._lazy import resolve
from snapflow.adapters.lerobot.plugin.configuration_snapflow import student_config_class
from snapflow.adapters.lerobot.registry import adapter_class
from snapflow.adapters.lerobot_types import LEROBOT_POLICY_TYPES, lerobot_policy_type


class SnapFlowStudent:
    """Mixed in before a LeRobot policy class."""

    def __init__(self, config: Any, **kwargs: Any) -> None:
        super().__init__(config, **kwargs)
        adapter_class(config.base_type)(self).use_sampling_mode(config.mode)

    def supports_rtc(self) -> bool:
        """LeRobot's guided real-time chunking runs in the teacher modes only (see ``check_rtc``)."""
        return not self.config.mode.jump and super().supports_rtc()

    @classmethod
    def _load_as_safetensor(cls, model: Any, model_file: str, map_location: str, strict: bool) -> Any:
        # LeRobot loads SmolVLA non-strictly: a missing phi_s would leave it at zero, the naive step under
        # SnapFlow's name
        return super()._load_as_safetensor(model, model_file, map_location, True)


def student_policy(base_type: str) -> type[SnapFlowStudent]:
    """The student policy class of the declared LeRobot type ``base_type``, made on first use."""
    declared = lerobot_policy_type(base_type)
    name = f"SnapFlow{declared.class_stem}Policy"
    if name not in globals():
        config_class = student_config_class(base_type)
        namespace = {"__module__": __name__, "__qualname__": name, "config_class": config_class}
        made = type(name, (SnapFlowStudent, resolve(declared.policy)), {**namespace, "name": declared.student_type})

        def __init__(self: Any, config: Any, **kwargs: Any) -> None:
            SnapFlowStudent.__init__(self, config, **kwargs)

        # LeRobot reads the config class off the annotation of ``config`` (a string under postponed annotations)
        __init__.__annotations__ = {"config": config_class, "return": None}
        made.__init__ = __init__
        globals()[name] = made
    return globals()[name]


for _declared in LEROBOT_POLICY_TYPES:
    student_policy(_declared)


__all__ = ["SnapFlowStudent", "student_policy"]
