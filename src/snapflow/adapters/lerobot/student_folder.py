"""What marks a LeRobot policy folder as a SnapFlow student, and the refusal to load one as its teacher's type.

A student folder is LeRobot's layout with phi_s inside. Asked for under its teacher's type (``smolvla`` for a
``snapflow_smolvla`` folder, or a student whose config was retyped by hand so that a LeRobot without the plugin
would read it), LeRobot builds the plain policy, loads it non-strictly (phi_s dropped with only an "unexpected keys"
warning) and samples with the teacher's denoising steps, while the folder still claims one step. Every place snapflow
loads such a folder under a type asks :func:`refuse_student_as_teacher` first.
"""

from __future__ import annotations

import json
from pathlib import Path

from snapflow.adapters.hub import HubError, fetch_hub_file, local_folder
from snapflow.policies.loaded import CheckpointError

STUDENT_TYPE_PREFIX = "snapflow_"  # a student's LeRobot policy type: snapflow_<the type it was distilled from>
TARGET_TIME_WEIGHTS = "model.target_time_embedding."  # phi_s, where the adapters keep it inside LeRobot's model
CONFIG_FILE = "config.json"  # LeRobot's names for a policy's config and weights
WEIGHTS_FILE = "model.safetensors"


class StudentAsTeacherError(CheckpointError):
    """A SnapFlow student's folder asked for under the LeRobot type of the teacher it was distilled from."""


def _file(source: str | Path, name: str) -> Path | None:
    """``name`` in the local folder or hub repo ``source`` (fetched into the cache, where LeRobot's own load then
    finds it), or None where it has none."""
    folder = local_folder(str(source))
    if folder is not None:
        return folder / name if (folder / name).is_file() else None
    try:
        return fetch_hub_file(str(source), name, "a LeRobot policy")
    except HubError:  # a file the repo lacks (a hub that stopped answering is named by the load that follows)
        return None


def _holds_target_time(weights: Path) -> bool:
    """Whether the safetensors file holds phi_s (its header alone is read)."""
    from safetensors import safe_open

    with safe_open(weights, framework="pt") as tensors:
        return any(name.startswith(TARGET_TIME_WEIGHTS) for name in tensors.keys())


def distilled_from(source: str | Path) -> str | None:
    """The LeRobot policy type the SnapFlow student at ``source`` (a local folder or a hub id) was distilled from, or
    None where it holds no student. A student says so by its config's type (``snapflow_<type>``) or, where its config
    is typed as the teacher (an export older than the student types, a config retyped by hand), by phi_s in its
    weights."""
    config = _file(source, CONFIG_FILE)
    if config is None:
        return None  # not a LeRobot policy: its loader names what is missing
    policy_type = str(json.loads(config.read_text()).get("type", ""))
    if policy_type.startswith(STUDENT_TYPE_PREFIX):
        return policy_type.removeprefix(STUDENT_TYPE_PREFIX)
    weights = _file(source, WEIGHTS_FILE)
    return policy_type if weights is not None and _holds_target_time(weights) else None


def refuse_student_as_teacher(source: str | Path, policy_type: str) -> None:
    """Raise :class:`StudentAsTeacherError` if ``source`` holds a SnapFlow student and ``policy_type`` is the type of
    the teacher it was distilled from."""
    teacher = distilled_from(source)
    if teacher is not None and policy_type == teacher:
        raise StudentAsTeacherError(
            f"{source} holds a SnapFlow student distilled from {teacher}: loaded as {policy_type!r}, LeRobot would "
            f"build a plain {teacher}, drop phi_s with only an 'unexpected keys' warning and sample with {teacher}'s "
            f"own denoising steps; load it as '{STUDENT_TYPE_PREFIX}{teacher}' (lerobot >= 0.5 with snapflow's "
            "plugin) or with snapflow.adapters.lerobot.load_distilled"
        )


__all__ = [
    "STUDENT_TYPE_PREFIX",
    "StudentAsTeacherError",
    "distilled_from",
    "refuse_student_as_teacher",
]
