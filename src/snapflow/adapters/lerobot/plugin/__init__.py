"""SnapFlow students as LeRobot policies of their own types, ``snapflow_<type>`` for each type
:mod:`snapflow.adapters.lerobot_types` declares (``snapflow_smolvla``, ``snapflow_pi0``, ``snapflow_pi05``):
LeRobot's config plus one field, ``sampling_mode`` (``snapflow-1`` by default, ``teacher-10`` to run the same
checkpoint as its teacher), and LeRobot's policy class plus phi_s, loaded strictly.

A student that ``snapflow distill --policy`` exports is saved under these types, so LeRobot's own tools
(``lerobot-eval --policy.path=...``, ``make_policy``, ``from_pretrained``) load it unchanged once the types are
registered. LeRobot >= 0.5 registers them itself: it imports every installed distribution named
``lerobot_policy_*``, and ``lerobot_policy_snapflow`` (``plugins/lerobot_policy_snapflow``) imports this package.
The module names follow LeRobot's convention (``configuration_*`` -> ``modeling_*`` / ``processor_*``), by which
its factory finds the policy class and the processors of a registered config type."""

from __future__ import annotations

from dataclasses import fields
from typing import Any

from snapflow.adapters.lerobot.plugin.configuration_snapflow import SnapFlowSampling, student_config_class
from snapflow.adapters.lerobot.plugin.modeling_snapflow import SnapFlowStudent, student_policy
from snapflow.adapters.lerobot.plugin.processor_snapflow import student_processors
from snapflow.flow.modes import SNAPFLOW_1, SamplingMode


def student_config(config: Any, mode: SamplingMode = SNAPFLOW_1) -> SnapFlowSampling:
    """``config`` (a plain LeRobot config, or a student's) as its student type, sampling with ``mode``."""
    base_type = config.base_type if isinstance(config, SnapFlowSampling) else config.type
    values = {field.name: getattr(config, field.name) for field in fields(config) if field.init}
    values["sampling_mode"] = mode.name
    return student_config_class(base_type)(**values)


__all__ = [
    "SnapFlowSampling",
    "SnapFlowStudent",
    "student_config_class",
    "student_policy",
    "student_processors",
    "student_config",
]
