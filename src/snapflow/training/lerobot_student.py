"""A LeRobot teacher made ready for ``lerobot-train`` to distil: the same weights typed as its SnapFlow student
(``snapflow_<type>``, phi_s at zero, ``distilled`` false), the distillation settings in its config, the teacher's
processors beside it. ``lerobot-train --policy.path=<that folder>`` then runs SnapFlow distillation with LeRobot's
own trainer, optimiser, Accelerate, logging and hub push (the student type's ``forward`` is the objective,
:mod:`snapflow.adapters.lerobot.plugin.modeling_snapflow`)."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Any

from snapflow.adapters.lerobot.plugin.configuration_snapflow import DISTILL_OPTIONS, SnapFlowSampling
from snapflow.errors import InvalidInputError
from snapflow.policies.loaded import CheckpointError
from snapflow.sources import open_policy
from snapflow.training.recipes import DistillSettings

# what lerobot-train runs beyond the settings a student's config holds: the paper's method as snapflow distils a
# LeRobot policy itself (training.lerobot.distill_lerobot refuses the rest too)
_FIXED = DistillSettings()


def student_fields(settings: DistillSettings) -> dict[str, Any]:
    """``settings`` as a student config's ``distill_*`` fields; a setting those fields cannot hold (another method
    or target, the ablations, a schedule of target steps, a trained prefix) is refused by name."""
    held = {name: getattr(settings, name) for name in DISTILL_OPTIONS}
    if not isinstance(settings.target_steps, int):
        raise InvalidInputError("a LeRobot student's config holds one number of target steps, not a schedule")
    if replace(settings, **{name: getattr(_FIXED, name) for name in DISTILL_OPTIONS}) != _FIXED:
        raise InvalidInputError(
            "lerobot-train distils with SnapFlow's Euler target, phi_s, the model's marginal velocity and the VLM "
            f"frozen; only {', '.join(DISTILL_OPTIONS)} may differ from the paper's settings"
        )
    return {f"distill_{name}": value for name, value in held.items()}


def config_settings(config: SnapFlowSampling) -> DistillSettings:
    """The distillation settings a student's config holds, as snapflow's own distillation reads them."""
    return DistillSettings(**config.distill_options())


def write_student(
    policy_path: str,
    output: str | Path,
    settings: DistillSettings | None = None,
    preprocessor_overrides: dict[str, Any] | None = None,
) -> Path:
    """The LeRobot pi0, pi0.5 or SmolVLA at ``policy_path`` (hub id or folder) written to ``output`` as its SnapFlow
    student, ready for ``lerobot-train --policy.path=output``: its weights with phi_s at zero (bit for bit the
    teacher), its config typed ``snapflow_<type>`` with ``distilled`` false (it refuses ``snapflow-N`` until trained)
    and ``settings`` (default: the paper's) as its ``distill_*`` fields, and the teacher's own processors (built
    from its config when its folder has none; ``lerobot-train`` gives them the dataset's statistics).

    A student given as ``policy_path`` keeps its phi_s and its ``distilled`` record: training it again continues
    the distillation."""
    from snapflow.adapters.lerobot.plugin import student_config
    from snapflow.training.lerobot import policy_processors

    fields = student_fields(settings or DistillSettings())
    opened = open_policy(policy_path)
    if opened.exported:
        raise CheckpointError(f"{policy_path} is an {opened.export['format']} export: it runs, it does not train")
    policy = opened.policy.policy
    config = student_config(policy.config)
    if not isinstance(policy.config, SnapFlowSampling):
        config.distilled = False
    for name, value in fields.items():
        setattr(config, name, value)
    output = Path(output)
    policy.save_pretrained(output)
    config._save_pretrained(output)
    for processor in policy_processors(policy, policy_path, None, preprocessor_overrides):
        processor.save_pretrained(output)
    return output


__all__ = ["config_settings", "student_fields", "write_student"]
