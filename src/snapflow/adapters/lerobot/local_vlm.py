"""A LeRobot policy folder that opens on any machine, from any working directory, where its VLM is a local folder (a
SmolVLA over a SmolVLM written by :func:`~snapflow.adapters.lerobot.smolvlm.write_smolvlm`: config, tokenizer and
processor, a few kB; an X-VLA trained from scratch reads that folder's tokenizer).

LeRobot names such a VLM by the path it was given, in the policy's ``config.json`` (SmolVLA's ``vlm_model_name``,
X-VLA's ``tokenizer_name``), LeRobot's ``train_config.json`` and the pre-processor's tokenizer step
(``tokenizer_name``): an absolute path of the machine that trained it makes the folder useless anywhere else.
:func:`bundle_vlm` copies the VLM folder into the policy folder (:data:`BUNDLED_VLM`) and names it there relative to
the policy folder. LeRobot reads these names relative to the working directory, so:

- snapflow's own commands hand them to LeRobot as absolute paths when they load such a folder
  (:func:`resolve_config`, :func:`saved_processors`);
- in a SnapFlow student's folder (``snapflow_<type>``) LeRobot's own tools (``lerobot-eval``, ``lerobot-train``) find
  them from any working directory too: the student policy's ``from_pretrained`` resolves the config's name against
  the folder (:mod:`~snapflow.adapters.lerobot.plugin.modeling_snapflow`), and :func:`bundle_vlm` gives the
  student's pre-processor snapflow's tokenizer step, which carries the tokenizer's files in its state
  (:class:`~snapflow.adapters.lerobot.plugin.processor_snapflow.SnapFlowTokenizerStep`). A ``lerobot-train``
  checkpoint of such a student names the VLM by absolute path again (LeRobot saves the config it trained with);
  keeping it bundles it anew;
- a teacher's folder (LeRobot's own type, which snapflow cannot hook and LeRobot 0.4.4 reads too) keeps LeRobot's
  tokenizer step: LeRobot's own tools open it only from inside it (``cd <folder> && lerobot-eval --policy.path=.``).
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Any

from snapflow.adapters.lerobot_types import LEROBOT_POLICY_TYPES
from snapflow.policies.loaded import CheckpointError
from snapflow.reporting.files import write_json

BUNDLED_VLM = "smolvlm"  # the local VLM's folder inside a policy folder
_CONFIG = "config.json"  # LeRobot's names for a policy's config, its training config and its pre-processor
_TRAIN_CONFIG = "train_config.json"
_PREPROCESSOR = "policy_preprocessor.json"
_TOKENIZER_STEP = "tokenizer_processor"  # the pre-processor step that loads the VLM's tokenizer
#: the config fields a LeRobot policy names its VLM's folder by, the first its config holds: SmolVLA's VLM, X-VLA's
#: tokenizer
_VLM_FIELDS = ("vlm_model_name", "tokenizer_name")


def _vlm_field(config: dict[str, Any]) -> str | None:
    """The field of ``config`` (a policy config's fields by name) that names its VLM's folder, if any."""
    return next((field for field in _VLM_FIELDS if field in config), None)


def _vlm_name(folder: Path) -> str | None:
    path = folder / _CONFIG
    if not path.is_file():
        return None
    config = json.loads(path.read_text())
    field = _vlm_field(config)
    return config[field] if field else None


def bundled_vlm(folder: str | Path) -> Path | None:
    """The VLM folder kept inside the policy folder ``folder``, as an absolute path, or None where its config names
    a hub model, an absolute path or no VLM at all; a :class:`CheckpointError` where the folder lacks the VLM it
    names as kept inside."""
    folder = Path(folder)
    name = _vlm_name(folder)
    if not name or Path(name).is_absolute():
        return None
    candidate = folder / name
    if (candidate / _CONFIG).is_file():
        return candidate.resolve()
    if name == BUNDLED_VLM:  # the name snapflow gives a VLM it keeps inside: never a hub model's
        raise CheckpointError(f"{folder} names its VLM {name}/, which the folder lacks (copy the whole folder)")
    return None


def bundle_vlm(folder: str | Path) -> bool:
    """Make the policy folder ``folder`` open on any machine and, for a SnapFlow student, in LeRobot's own tools from
    any working directory; True where anything changed. A local VLM folder that ``folder`` names by an absolute path
    is copied into ``folder/smolvlm`` and named there by that relative path in every file of ``folder`` that names
    it (the copy whole before any file names it). A student's pre-processor then carries its tokenizer in its
    tokenizer step's state (also where its VLM was inside already); a teacher's keeps LeRobot's step. Nothing changes
    where the folder names a hub model."""
    folder = Path(folder)
    moved = _move_vlm_inside(folder)
    carried = _carry_tokenizer(folder)
    return moved or carried


def _move_vlm_inside(folder: Path) -> bool:
    """:func:`bundle_vlm`'s copy of a VLM named by an absolute path into the folder (False: no such VLM)."""
    name = _vlm_name(folder)
    if not name or not Path(name).is_absolute():
        return False
    source = Path(name)
    if not (source / _CONFIG).is_file():
        raise FileNotFoundError(f"{folder / _CONFIG} names the local VLM {source}, which is not there")
    partial = folder / f".{BUNDLED_VLM}.partial"
    shutil.rmtree(partial, ignore_errors=True)
    shutil.copytree(source, partial)
    shutil.rmtree(folder / BUNDLED_VLM, ignore_errors=True)
    partial.rename(folder / BUNDLED_VLM)
    _rename_vlm(folder, name, BUNDLED_VLM)
    return True


def _carry_tokenizer(folder: Path) -> bool:
    """In a SnapFlow student's folder, LeRobot's tokenizer step that reads the VLM kept inside (by a name LeRobot
    reads from the working directory) replaced by snapflow's, which carries the tokenizer's files in its state, a
    ``.safetensors`` file beside the pre-processor named as LeRobot names a step's; the other steps and their files
    are left as they are. False where the folder is a teacher's (LeRobot's own type) or has no such step."""
    from safetensors.torch import save_file

    from snapflow.adapters.lerobot.plugin.processor_snapflow import TOKENIZER_STEP, SnapFlowTokenizerStep

    override = _tokenizer_override(folder)  # none without a config naming a VLM inside
    if not override or json.loads((folder / _CONFIG).read_text()).get("type") not in _student_types():
        return False
    content = json.loads((folder / _PREPROCESSOR).read_text())
    for index, step in enumerate(content["steps"]):
        if step.get("registry_name") == _TOKENIZER_STEP:
            carried = SnapFlowTokenizerStep(**{**step["config"], **override[_TOKENIZER_STEP]})
            state_file = f"{Path(_PREPROCESSOR).stem}_step_{index}_{TOKENIZER_STEP}.safetensors"
            save_file(carried.state_dict(), folder / state_file)
            content["steps"][index] = {
                "registry_name": TOKENIZER_STEP,
                "config": carried.get_config(),
                "state_file": state_file,
            }
    write_json(folder / _PREPROCESSOR, content)
    return True


def _student_types() -> set[str]:
    """The LeRobot types of the SnapFlow students, ``snapflow_<type>``."""
    return {declared.student_type for declared in LEROBOT_POLICY_TYPES.values()}


def _rename_vlm(folder: Path, old: str, new: str) -> None:
    """Replace the VLM's name ``old`` by ``new`` in the config, the training config and the pre-processor."""
    config = json.loads((folder / _CONFIG).read_text())
    field = _vlm_field(config)
    write_json(folder / _CONFIG, {**config, field: new})
    train_config = folder / _TRAIN_CONFIG
    if train_config.is_file():
        content = json.loads(train_config.read_text())
        if content.get("policy", {}).get(field) == old:
            content["policy"][field] = new
            write_json(train_config, content)
    preprocessor = folder / _PREPROCESSOR
    if preprocessor.is_file():
        content = json.loads(preprocessor.read_text())
        for step in content["steps"]:
            if step.get("registry_name") == _TOKENIZER_STEP and step["config"].get("tokenizer_name") == old:
                step["config"]["tokenizer_name"] = new
        write_json(preprocessor, content)


def resolve_config(config: Any, folder: str | Path) -> Any:
    """``config`` (LeRobot's, loaded from the policy folder ``folder``) naming its bundled VLM by absolute path, as
    LeRobot builds the model from it; unchanged for any other policy, and where ``config`` names another VLM than the
    folder's config does (a name given on LeRobot's command line)."""
    vlm = bundled_vlm(folder)
    if vlm is not None:
        field = _vlm_field(vars(config))
        if getattr(config, field) == _vlm_name(Path(folder)):
            setattr(config, field, str(vlm))
    return config


def _tokenizer_override(folder: str | Path) -> dict[str, Any]:
    """LeRobot's ``preprocessor_overrides`` that point LeRobot's own tokenizer step at the policy folder's bundled
    VLM (none where the folder keeps no VLM inside, or its pre-processor has no such step: a student's carries its
    tokenizer in snapflow's step, and LeRobot refuses an override no step takes)."""
    vlm = bundled_vlm(folder)
    preprocessor = Path(folder) / _PREPROCESSOR
    if vlm is None or not preprocessor.is_file():
        return {}
    steps = json.loads(preprocessor.read_text())["steps"]
    if not any(step.get("registry_name") == _TOKENIZER_STEP for step in steps):
        return {}
    return {_TOKENIZER_STEP: {"tokenizer_name": str(vlm)}}


def saved_processors(
    config: Any,
    folder: str | Path,
    device: str,
    overrides: dict[str, Any] | None = None,
    postprocessor_overrides: dict[str, Any] | None = None,
) -> tuple[Any, Any]:
    """LeRobot's pre- and post-processors saved with the policy at ``folder`` (a local folder or hub id), on
    ``device``, the tokenizer step pointed at a VLM kept inside the folder; ``overrides`` (LeRobot's
    ``preprocessor_overrides``) and ``postprocessor_overrides`` win. A student's tokenizer step, snapflow's, is
    registered with LeRobot here (LeRobot >= 0.5 imports it in its own tools; 0.4.4 never does)."""
    from lerobot.policies.factory import make_pre_post_processors

    import snapflow.adapters.lerobot.plugin.processor_snapflow  # noqa: F401 - registers the students' tokenizer step

    preprocessor = {"device_processor": {"device": device}, **_tokenizer_override(folder), **(overrides or {})}
    return make_pre_post_processors(
        config,
        pretrained_path=str(folder),
        preprocessor_overrides=preprocessor,
        postprocessor_overrides=postprocessor_overrides or {},
    )


__all__ = ["BUNDLED_VLM", "bundled_vlm", "bundle_vlm", "resolve_config", "saved_processors"]
