"""The student configs: LeRobot's SmolVLA / pi0 / pi0.5 config plus how the student samples (``sampling_mode``),
whether it was distilled (``distilled``) and what ``lerobot-train`` distils it with (``distill_*``), registered with
LeRobot's config registry under ``snapflow_<type>``."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar

from lerobot.configs.policies import PreTrainedConfig
from lerobot.policies.pi0.configuration_pi0 import PI0Config
from lerobot.policies.pi05.configuration_pi05 import PI05Config
from lerobot.policies.smolvla.configuration_smolvla import SmolVLAConfig

from snapflow.flow.modes import SNAPFLOW_1, SamplingMode
from snapflow.objective.registry import make_objective

#: the SnapFlow objective's settings a student's config holds, each as ``distill_<name>`` (the names of
#: :class:`snapflow.training.recipes.DistillSettings`' fields)
DISTILL_OPTIONS = ("alpha", "consistency_weight", "target_steps", "teacher_velocity_clamp")


@dataclass
class SnapFlowSampling:
    """What a student's config adds to its LeRobot config.

    ``sampling_mode``: how LeRobot's ``select_action`` / ``predict_action_chunk`` sample, ``snapflow-N`` (one jump by
    default) or ``teacher-N`` (the same checkpoint as its flow-matching teacher). ``distilled``: whether SnapFlow
    distillation trained it (True: ``snapflow distill``, or ``lerobot-train`` steps of the SnapFlow objective; False:
    a teacher's weights typed as a student and not trained yet, or trained last by flow matching alone, which wears
    the jump away; None: not recorded, a folder ``snapflow distill`` wrote before the field existed, all distilled).
    A student whose ``distilled`` is False refuses ``snapflow-N`` by name. ``distill_*``: the SnapFlow objective the
    student type's ``forward`` computes, so ``lerobot-train`` distils it (the paper's settings by default).
    """

    #: the LeRobot policy type the student was distilled from
    base_type: ClassVar[str]
    sampling_mode: str = SNAPFLOW_1.name
    distilled: bool | None = None
    distill_alpha: float = 0.5
    distill_consistency_weight: float = 0.1
    distill_target_steps: int = 2
    distill_teacher_velocity_clamp: float | None = None

    def __post_init__(self) -> None:
        super().__post_init__()  # the LeRobot config's own checks
        SamplingMode.parse(self.sampling_mode)  # a named error for an unknown mode, at load time
        make_objective("snapflow", **self.distill_options())  # the objective checks its settings, at load time too

    @property
    def mode(self) -> SamplingMode:
        return SamplingMode.parse(self.sampling_mode)

    def distill_options(self) -> dict[str, Any]:
        """The ``distill_*`` fields by the names of the objective's (and ``DistillSettings``') options."""
        return {name: getattr(self, f"distill_{name}") for name in DISTILL_OPTIONS}


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


__all__ = ["DISTILL_OPTIONS", "SnapFlowSampling", "SnapFlowSmolVLAConfig", "SnapFlowPI0Config", "SnapFlowPI05Config"]
