"""The student configs: each declared LeRobot type's config plus how the student samples (``sampling_mode``),
whether it was distilled (``distilled``) and what ``lerobot-train`` distils it with (``distill_*``), registered with
LeRobot's config registry under ``snapflow_<type>`` as ``SnapFlow<stem>Config`` in this module (where LeRobot's
factory looks)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar

from lerobot.configs.policies import PreTrainedConfig

from snapflow._lazy import resolve
from snapflow.adapters.lerobot_types import installed_lerobot_types, lerobot_policy_type
from snapflow.flow.modes import SNAPFLOW_1, SamplingMode
from snapflow.flow.time_sampling import BetaTimeSampler, TimeSampler, shifted
from snapflow.objective.base import TwoBranchObjective
from snapflow.objective.options import PAPER_ALPHA, PAPER_CONSISTENCY_WEIGHT, PAPER_TARGET_STEPS
from snapflow.objective.registry import make_objective

#: the SnapFlow objective's settings a student's config holds, each as ``distill_<name>`` (the names of
#: :class:`snapflow.training.recipes.DistillSettings`' fields)
DISTILL_OPTIONS = ("alpha", "consistency_weight", "target_steps", "teacher_velocity_clamp", "time_shift")


@dataclass
class SnapFlowSampling:
    """What a student's config adds to its LeRobot config.

    ``sampling_mode``: how LeRobot's ``select_action`` / ``predict_action_chunk`` sample, ``snapflow-N`` (one jump by
    default) or ``teacher-N`` (the same checkpoint as its flow-matching teacher). ``distilled``: whether SnapFlow
    distillation trained it (True: ``snapflow distill``, or ``lerobot-train`` steps of the SnapFlow objective; False:
    a teacher's weights typed as a student and not trained yet, or trained last by flow matching alone, which wears
    the jump away; None: not recorded, a folder ``snapflow distill`` wrote before the field existed, all distilled).
    A student whose ``distilled`` is False refuses ``snapflow-N`` by name. ``distill_*``: the SnapFlow objective the
    student type's ``forward`` computes, so ``lerobot-train`` distils it (the paper's settings by default;
    ``distill_alpha=1`` with ``distill_time_shift=4`` is arXiv 2606.05737's high-noise-biased fine-tuning instead,
    which leaves it not distilled: it samples as ``naive`` or ``teacher-N``).
    """

    #: the LeRobot policy type the student was distilled from
    base_type: ClassVar[str]
    sampling_mode: str = SNAPFLOW_1.name
    distilled: bool | None = None
    distill_alpha: float = PAPER_ALPHA
    distill_consistency_weight: float = PAPER_CONSISTENCY_WEIGHT
    distill_target_steps: int = PAPER_TARGET_STEPS
    distill_teacher_velocity_clamp: float | None = None
    distill_time_shift: float = 1.0

    def __post_init__(self) -> None:
        super().__post_init__()  # the LeRobot config's own checks
        SamplingMode.parse(self.sampling_mode)  # a named error for an unknown mode, at load time
        self.distillation_objective(BetaTimeSampler())  # the objective checks its settings, at load time too

    @property
    def mode(self) -> SamplingMode:
        return SamplingMode.parse(self.sampling_mode)

    def distill_options(self) -> dict[str, Any]:
        """The ``distill_*`` fields by the names of ``DistillSettings``' fields."""
        return {name: getattr(self, f"distill_{name}") for name in DISTILL_OPTIONS}

    def distillation_objective(self, time_sampler: TimeSampler) -> TwoBranchObjective:
        """The SnapFlow objective of the ``distill_*`` fields, its flow-matching times ``time_sampler``'s (the
        policy's own) shifted by ``distill_time_shift``."""
        options = self.distill_options()
        shift = options.pop("time_shift")
        return make_objective("snapflow", time_sampler=shifted(time_sampler, shift), **options)


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


for _declared in installed_lerobot_types():  # the declared types' classes exist as soon as the plugin is imported
    student_config_class(_declared)


__all__ = ["DISTILL_OPTIONS", "SnapFlowSampling", "student_config_class"]
