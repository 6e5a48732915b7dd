"""The student configs: each declared LeRobot type's config plus how the student samples (``sampling_mode``),
whether it was distilled (``distilled``) and what ``lerobot-train`` distils it with (``distill``: the
:class:`~snapflow.objective.settings.DistillSettings` that ``snapflow distill`` takes, nested as LeRobot nests a
config, so ``--policy.distill.<field>`` sets each), registered with LeRobot's config registry under
``snapflow_<type>`` as ``SnapFlow<stem>Config`` in this module (where LeRobot's factory looks).

A ``config.json`` written before the settings were nested holds them as flat ``distill_<field>`` keys: LeRobot's
parser (draccus) reads those too, into ``distill``, and never writes them."""

from __future__ import annotations

from dataclasses import dataclass, field, fields, replace
from typing import Any, ClassVar

import draccus
from draccus.choice_types import CHOICE_TYPE_KEY
from draccus.parsers import decoding
from draccus.parsers.encoding import encode_dataclass
from lerobot.configs.policies import PreTrainedConfig

from snapflow._lazy import resolve
from snapflow.adapters.lerobot_types import installed_lerobot_types, lerobot_policy_type
from snapflow.errors import InvalidInputError
from snapflow.flow.modes import SNAPFLOW_1, SamplingMode
from snapflow.objective.options import TeacherVelocity
from snapflow.objective.settings import DistillSettings

#: the keys a student's ``config.json`` held its distillation settings under before they were nested in ``distill``
#: (``distill_<field>`` of each :class:`DistillSettings` field they held)
FLAT_DISTILL_KEYS = tuple(
    f"distill_{name}"
    for name in ("alpha", "consistency_weight", "target_steps", "teacher_velocity_clamp", "time_shift")
)


_DEFAULTS = {field.name: field.default for field in fields(DistillSettings)}


def _flat_key() -> Any:
    """A field that only an older ``config.json`` sets (after the config is built, as draccus sets a field outside
    ``__init__``): no flag, no repr, always None when read."""
    return field(default=None, init=False, repr=False, compare=False)


def check_student_settings(settings: DistillSettings) -> None:
    """Refuse, by name, what a LeRobot policy's student cannot be distilled with (snapflow's trainer and
    ``lerobot-train`` alike): a student type carries phi_s, so the no-phi_s ablation runs on built-in policies."""
    if not settings.target_time:
        raise InvalidInputError(
            "a LeRobot policy's student carries phi_s (its target-time embedding): the no-phi_s ablation "
            "(target_time false) runs on the built-in policies (snapflow train --policy-type ...)"
        )


@dataclass
class SnapFlowSampling:
    """What a student's config adds to its LeRobot config.

    ``sampling_mode``: how LeRobot's ``select_action`` / ``predict_action_chunk`` sample, ``snapflow-N`` (one jump by
    default) or ``teacher-N`` (the same checkpoint as its flow-matching teacher). ``distilled``: whether SnapFlow
    distillation trained it (True: ``snapflow distill``, or ``lerobot-train`` steps of a one-step objective; False:
    a teacher's weights typed as a student and not trained yet, or trained last by flow matching alone, which wears
    the jump away; None: not recorded, a folder ``snapflow distill`` wrote before the field existed, all distilled).
    A student whose ``distilled`` is False refuses ``snapflow-N`` by name.

    ``distill``: what the student type's ``forward`` computes, so ``lerobot-train`` distils it: every setting of
    ``snapflow distill`` (the paper's by default; ``alpha=1`` with ``time_shift=4`` is arXiv 2606.05737's
    high-noise-biased fine-tuning instead, which leaves it not distilled: it samples as ``naive`` or ``teacher-N``),
    checked as the config is built or loaded. ``distill_steps``: the ``lerobot-train`` steps a schedule of target
    steps (``distill.target_steps`` a list) splits into its equal stages (LeRobot gives a policy no step count; a
    schedule is refused at the first step without it). ``steps_distilled``: the optimiser steps this config was
    distilled for, counted by the policy's ``update`` and saved with each checkpoint, so a resumed run goes on at
    its stage.
    """

    #: the LeRobot policy type the student was distilled from
    base_type: ClassVar[str]
    sampling_mode: str = SNAPFLOW_1.name
    distilled: bool | None = None
    distill: DistillSettings = field(default_factory=DistillSettings)
    distill_steps: int | None = None
    steps_distilled: int = 0
    distill_alpha: float | None = _flat_key()
    distill_consistency_weight: float | None = _flat_key()
    distill_target_steps: int | None = _flat_key()
    distill_teacher_velocity_clamp: float | None = _flat_key()
    distill_time_shift: float | None = _flat_key()

    def __post_init__(self) -> None:
        super().__post_init__()  # the LeRobot config's own checks
        SamplingMode.parse(self.sampling_mode)  # a named error for an unknown mode, at load time
        check_student_settings(self.distill)  # DistillSettings checked its own values as it was built

    def __setattr__(self, name: str, value: Any) -> None:
        """An older ``config.json``'s flat key (None: its default) sets its field of ``distill``, checked; unless a
        flag (``--policy.distill.<field>``: such a file has no ``distill``) set that field off its default first."""
        if name in FLAT_DISTILL_KEYS:
            key = name.removeprefix("distill_")
            if value is None or getattr(self.distill, key) != _DEFAULTS[key]:
                return
            name, value = "distill", replace(self.distill, **{key: value})
        super().__setattr__(name, value)

    @property
    def mode(self) -> SamplingMode:
        return SamplingMode.parse(self.sampling_mode)


def _encode(config: SnapFlowSampling, declared_type: Any = None) -> dict[str, Any]:
    """A student config as LeRobot writes it (its type first), without the flat keys it only reads."""
    encoded = encode_dataclass(config)
    return {CHOICE_TYPE_KEY: config.type, **{key: encoded[key] for key in encoded if key not in FLAT_DISTILL_KEYS}}


try:  # draccus >= 0.11 (LeRobot >= 0.5): its own registry, told to dispatch on subclasses
    draccus.encode.register(SnapFlowSampling, _encode, include_subclasses=True)
except TypeError:  # draccus 0.10 (LeRobot 0.4): functools.singledispatch, which does
    draccus.encode.register(SnapFlowSampling, _encode)
if not hasattr(decoding, "decode_literal"):  # draccus 0.10 decodes no Literal: DistillSettings checks the text
    draccus.decode.register(TeacherVelocity, lambda raw, path=(): str(raw))


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


__all__ = ["FLAT_DISTILL_KEYS", "SnapFlowSampling", "check_student_settings", "student_config_class"]
