"""LeRobot policies snapflow trained, on disk: LeRobot's own layout (``config.json`` + ``model.safetensors``; a
distilled one typed as its SnapFlow student, ``snapflow_<type>``, with phi_s inside) plus a marker, ``snapflow.json``: which adapter rebuilds it, whether it was
distilled, and the share of each task's episodes its training held out (for offline metrics)."""

from __future__ import annotations

import copy
import json
from pathlib import Path
from typing import Any

from torch import nn

from snapflow.adapters.hub import check_source
from snapflow.adapters.lerobot.base import LeRobotFlowPolicy
from snapflow.adapters.lerobot.local_vlm import resolve_config
from snapflow.adapters.lerobot.registry import adapter_class, base_policy_type, wrap_policy
from snapflow.flow.modes import SNAPFLOW_1, SamplingMode
from snapflow.objective.settings import DistillSettings
from snapflow.policies.checkpoint import CheckpointError, load_state_strict, read_tensors
from snapflow.reporting.files import write_json

SNAPFLOW_MARKER = "snapflow.json"
SAFETENSORS_FILE = "model.safetensors"  # LeRobot's name for a policy's weights
PREPROCESSOR_FILE = "policy_preprocessor.json"  # LeRobot's name for a saved pre-processor


def marker_of(policy_type: str, distilled: bool, val_fraction: float) -> dict[str, Any]:
    """``snapflow.json``'s content for a LeRobot policy folder of ``policy_type``."""
    return {"format": "snapflow-lerobot", "policy": policy_type, "target_time": distilled, "val_fraction": val_fraction}


def _write_marker(directory: Path, policy_type: str, distilled: bool, val_fraction: float) -> None:
    write_marker(directory, marker_of(policy_type, distilled, val_fraction))


def write_marker(directory: str | Path, marker: dict[str, Any]) -> None:
    """``snapflow.json`` of a LeRobot policy folder, written whole."""
    write_json(Path(directory) / SNAPFLOW_MARKER, marker)


def load_student_config(directory: str | Path) -> Any:
    """The LeRobot config of a policy folder, a SnapFlow student's type included, naming a VLM kept inside the
    folder by its absolute path; a config that does not load (an unknown sampling mode, a bad field) is named."""
    from lerobot.configs.policies import PreTrainedConfig

    import snapflow.adapters.lerobot.plugin  # noqa: F401 - registers the student types

    directory = Path(directory)
    try:
        return resolve_config(PreTrainedConfig.from_pretrained(directory), directory)
    except Exception as error:  # draccus wraps the config's own error
        raise CheckpointError(f"{directory / 'config.json'} does not load: {error.__cause__ or error}") from None


def read_marker(directory: str | Path) -> dict | None:
    """``snapflow.json`` of a LeRobot policy folder, or None for a policy snapflow did not train."""
    marker = Path(directory) / SNAPFLOW_MARKER
    if not marker.is_file():
        return None
    try:
        content = json.loads(marker.read_text())
        content["policy"], content["target_time"]
    except (json.JSONDecodeError, KeyError, TypeError) as error:
        raise CheckpointError(f"{marker} is corrupt ({error})") from None
    return content


def save_distilled(
    adapter: LeRobotFlowPolicy,
    directory: str | Path,
    val_fraction: float = 0.0,
    settings: DistillSettings | None = None,
) -> Path:
    """The distilled policy in LeRobot's layout, its config typed as its SnapFlow student (sampling one step), so
    LeRobot's ``lerobot-eval --policy.path`` loads it through snapflow's plugin.

    Args:
        adapter: the distilled adapter (:func:`wrap_policy` of a LeRobot policy, trained).
        directory: the folder to write (``config.json``, ``model.safetensors`` and snapflow's marker).
        val_fraction: the share of each task's episodes its training held out, recorded for evaluation.
        settings: what it was distilled with, in its config's ``distill`` (what ``lerobot-train`` on it goes on
            with); None: the config's own.

    Returns:
        ``directory``, which :func:`load_distilled` and ``lerobot-eval --policy.path`` open.
    """
    from snapflow.adapters.lerobot.plugin import student_config

    directory = Path(directory)
    adapter.policy.save_pretrained(directory)
    config = student_config(adapter.policy.config)
    config.distilled = True
    if settings is not None:
        config.distill = settings
    config._save_pretrained(directory)
    _write_marker(directory, adapter.policy_type, True, val_fraction)
    return directory


def save_teacher(adapter: LeRobotFlowPolicy, directory: str | Path, val_fraction: float) -> Path:
    """The adapted policy as its plain LeRobot self, without phi_s (which a teacher never trains): what LeRobot's
    ``from_pretrained`` and ``snapflow distill --policy`` load."""
    state = {
        name: tensor
        for name, tensor in adapter.policy.state_dict().items()
        if not name.startswith("model.target_time_embedding.")
    }
    plain = type(adapter.policy)(adapter.policy.config)
    plain.load_state_dict(state, strict=True)
    directory = Path(directory)
    plain.save_pretrained(directory)
    _write_marker(directory, adapter.policy_type, False, val_fraction)
    return directory


def rebuilt_on_cpu(adapter: LeRobotFlowPolicy) -> LeRobotFlowPolicy:
    """The adapter's policy built again from its config on the CPU, random weights and a fresh phi_s, for whole
    weights to be loaded into (a student trained sharded over several devices, exported from one process). It keeps
    the trained policy's config, the device it names included."""
    config = copy.copy(adapter.policy.config)
    config.device = "cpu"  # LeRobot's policies move themselves to their config's device as they are built
    plain = type(adapter.policy)(config)
    plain.config = adapter.policy.config
    return wrap_policy(plain)


def load_distilled(directory: str | Path, mode: SamplingMode = SNAPFLOW_1) -> LeRobotFlowPolicy:
    """Rebuild a saved SnapFlow policy as its student type, load every tensor strictly, and make LeRobot's own
    action API sample with ``mode``, in eval mode. (LeRobot's ``from_pretrained`` loads a plain SmolVLA
    non-strictly, so on its own it would silently drop phi_s and give back the teacher.)

    Args:
        directory: a folder :func:`save_distilled` wrote.
        mode: how LeRobot's ``select_action`` / ``predict_action_chunk`` sample (SnapFlow 1-NFE by default).

    Returns:
        The student's adapter; ``adapter.policy`` is the LeRobot policy.

    Raises:
        CheckpointError: the folder is not a distilled policy (no marker, a teacher's, or a config of another
            type than its marker's).
    """
    from snapflow.adapters.lerobot.plugin import student_config, student_policy

    directory = Path(directory)
    marker = read_marker(directory)
    if marker is None:
        raise CheckpointError(f"{directory} is not a SnapFlow-distilled LeRobot policy (no {SNAPFLOW_MARKER})")
    if not marker["target_time"]:
        raise CheckpointError(f"{directory} is a flow-matching teacher snapflow trained, not a distilled policy")
    policy_type = marker["policy"]
    config = load_student_config(directory)
    if base_policy_type(config) != policy_type:
        raise CheckpointError(f"{directory} holds a {config.type!r} config but its marker says {policy_type!r}")
    adapter_class(policy_type)  # the installed LeRobot serves it
    policy = student_policy(policy_type)(student_config(config, mode))  # a plain config: an older export
    load_state_strict(policy, read_tensors(directory / SAFETENSORS_FILE), directory / SAFETENSORS_FILE)
    return wrap_policy(policy).eval()  # as LeRobot's from_pretrained leaves a policy: X-VLA's dropout off


def _not_a_policy(path: str, error: ValueError) -> str:
    """Why the folder or hub repo ``path`` does not load as a LeRobot policy, and for a GR00T N1.7 base checkpoint
    (NVIDIA's format: no LeRobot type, no robot's features) what makes one of it."""
    config = Path(path) / "config.json"
    architectures = json.loads(config.read_text()).get("architectures", []) if config.is_file() else []
    if any(str(name).startswith("GR00T") for name in architectures):
        return (
            f"{path} is a GR00T N1.7 base checkpoint (NVIDIA's format), not a LeRobot policy: LeRobot's GrootPolicy "
            f"first learns a robot's features and statistics from a dataset over it (lerobot-train "
            f"--policy.type=groot --policy.base_model_path={Path(path).resolve()} --dataset.repo_id=<dataset> ...: "
            "an absolute path, which LeRobot does not take for a hub id); distil the "
            "policy folder that writes (<output_dir>/checkpoints/last/pretrained_model). Over a checkpoint "
            "snapflow's writer made, offline: python -m snapflow.adapters.lerobot.groot_checkpoint DIR --dataset "
            "<dataset root> writes one in DIR/lerobot_policy"
        )
    return f"{path} is not a LeRobot policy LeRobot can load: {error}"


def load_pretrained_policy(path: str) -> nn.Module:
    """A LeRobot policy from a hub id or a local pretrained directory, as ``lerobot-eval`` loads it; a mistyped
    folder, an unreachable hub or an unusable repo is named in one line before anything loads, and a SnapFlow student
    whose config is typed as its teacher is refused (:class:`~.student_folder.StudentAsTeacherError`)."""
    from huggingface_hub.constants import CONFIG_NAME

    check_source(path, CONFIG_NAME, "a LeRobot policy")  # before LeRobot's loaders import (seconds)
    from lerobot.configs.policies import PreTrainedConfig
    from lerobot.policies.factory import get_policy_class

    from snapflow.adapters.lerobot.plugin import SnapFlowSampling, student_policy  # registers the student types
    from snapflow.adapters.lerobot.student_folder import refuse_student_as_teacher

    try:
        own_config = PreTrainedConfig.from_pretrained(path)
    except ValueError as error:  # LeRobot's "Missing 'type' field", a type no installed plugin registered
        raise CheckpointError(_not_a_policy(path, error)) from None
    # a VLM kept inside the folder named by its absolute path: LeRobot reads the name from the working directory
    config = resolve_config(own_config, path)
    adapter_class(base_policy_type(config))
    if isinstance(config, SnapFlowSampling):  # LeRobot < 0.5 resolves only its own types
        return student_policy(config.base_type).from_pretrained(path, config=config)
    refuse_student_as_teacher(path, config.type)  # a student typed as its teacher: LeRobot's loader would drop phi_s
    return get_policy_class(config.type).from_pretrained(path, config=config)


__all__ = [
    "PREPROCESSOR_FILE",
    "SAFETENSORS_FILE",
    "SNAPFLOW_MARKER",
    "write_marker",
    "marker_of",
    "load_student_config",
    "read_marker",
    "save_distilled",
    "save_teacher",
    "rebuilt_on_cpu",
    "load_distilled",
    "load_pretrained_policy",
]
