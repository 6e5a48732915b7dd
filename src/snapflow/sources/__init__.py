"""What is at a path: :func:`open_policy` opens a built-in checkpoint, a LeRobot folder or hub id, or an export of
either, as one :class:`~snapflow.policies.loaded.OpenedPolicy`; the kinds it recognises are registered here, in one
place, in the order they are tried."""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import NoReturn

from snapflow import install_command
from snapflow._lazy import resolve
from snapflow.adapters.hub import check_source, local_folder
from snapflow.policies.checkpoint import LATEST, POLICY_CONFIG, is_builtin_checkpoint
from snapflow.policies.loaded import CheckpointError, OpenedPolicy


@dataclass(frozen=True)
class SourceKind:
    """A kind of policy source: what it is (for errors), whether it is at a local folder (None: a hub id), and the
    function that opens it (``"module:function"``, imported on first use: LeRobot is an optional extra)."""

    name: str
    description: str
    recognises: Callable[[Path | None], bool]
    opener: str
    extra: str | None = None  # the pip extra its opener needs
    #: a cheap check of the source run before the opener's module is imported (a hub repo named in one line in
    #: seconds, before an import of LeRobot that takes longer than the answer)
    precheck: Callable[[str], None] | None = None

    def open(self, source: str) -> OpenedPolicy:
        if self.precheck is not None:
            self.precheck(source)
        try:
            opener = resolve(self.opener)
        except ImportError as error:
            hint = f": {install_command(self.extra)}" if self.extra else ""
            raise CheckpointError(f"{source} is {self.description}, and {error}{hint}") from None
        return opener(source)


SOURCE_KINDS: list[SourceKind] = []

#: ``policy.json``'s format in a training checkpoint snapflow's trainer wrote of a LeRobot policy (it resumes a run)
LEROBOT_RUN_FORMAT = "snapflow-lerobot-run"
#: the LeRobot policy folder such a run exports beside its checkpoints when it finishes: what opens as a policy
LEROBOT_EXPORT_DIRECTORY = "lerobot_policy"


def _lerobot_run_checkpoint(folder: Path | None) -> Path | None:
    """The LeRobot training checkpoint at ``folder`` (a checkpoint folder, or a run folder whose latest it is)."""
    if folder is None:
        return None
    checkpoint = folder
    if not (folder / POLICY_CONFIG).is_file() and (folder / LATEST).is_file():
        checkpoint = folder / json.loads((folder / LATEST).read_text())["checkpoint"]
    try:
        return (
            checkpoint
            if json.loads((checkpoint / POLICY_CONFIG).read_text()).get("format") == LEROBOT_RUN_FORMAT
            else None
        )
    except (FileNotFoundError, json.JSONDecodeError):
        return None


def refuse_lerobot_run(source: str) -> NoReturn:
    """Refuse a LeRobot training checkpoint given where a policy is expected, naming the policy folder to pass: the
    one its run exported (in the run folder, or kept beside the checkpoint)."""
    checkpoint = _lerobot_run_checkpoint(Path(source))
    assert checkpoint is not None
    candidates = [
        folder / LEROBOT_EXPORT_DIRECTORY for folder in (Path(source), checkpoint.parent, checkpoint.parent.parent)
    ]
    exported = next((folder for folder in candidates if (folder / "config.json").is_file()), None)
    where = (
        f"pass its policy folder {exported}"
        if exported is not None
        else f"pass the policy folder its run exports when it finishes ({LEROBOT_EXPORT_DIRECTORY}/ in the run's folder)"
    )
    raise CheckpointError(f"{source} is a training checkpoint of a LeRobot policy, which resumes training; {where}")


def register_source_kind(kind: SourceKind) -> None:
    """Add a kind of policy source, tried after those registered before it."""
    if any(known.name == kind.name for known in SOURCE_KINDS):
        raise ValueError(f"a source kind named {kind.name!r} is registered already")
    SOURCE_KINDS.append(kind)


register_source_kind(
    SourceKind(
        "lerobot-run",
        "a LeRobot run's training checkpoint (refused: its exported policy folder opens)",
        lambda folder: _lerobot_run_checkpoint(folder) is not None,
        "snapflow.sources:refuse_lerobot_run",
    )
)
register_source_kind(
    SourceKind(
        "snapflow",
        "a snapflow checkpoint or run folder (policy.json or latest.json), or an export of one",
        lambda folder: folder is not None and is_builtin_checkpoint(folder),
        "snapflow.policies.checkpoint:load_policy",
    )
)
register_source_kind(
    SourceKind(
        "lerobot",
        "a LeRobot policy folder (config.json), an export of one, or a hub id (owner/name)",
        lambda folder: folder is None or (folder / "config.json").is_file(),
        "snapflow.adapters.lerobot.evaluation:load_lerobot_policy",
        extra="lerobot",
        precheck=lambda source: check_source(source, "config.json", "a LeRobot policy"),
    )
)


def open_policy(source: str | Path) -> OpenedPolicy:
    """The policy at ``source`` (a local folder, or a Hugging Face Hub id), opened by the first registered kind that
    recognises it; anything else is a :class:`CheckpointError` listing what a source may be. A mistyped local path
    is named as such, never looked up on the hub.

    Args:
        source: a built-in checkpoint or run folder, a LeRobot policy folder or hub id (``owner/name``), or an
            export of either.

    Returns:
        The policy with its processor, whether it was distilled, its export record if it is one, its flow-matching
        times and :meth:`~snapflow.policies.loaded.OpenedPolicy.check_mode`.

    Raises:
        CheckpointError: nothing snapflow can open is at ``source``, or its kind's extra is not installed.

    Examples:
        A built-in MLP teacher written to a folder, opened again; a jump mode is refused by name, since it was never
        distilled:

        >>> import tempfile
        >>> from pathlib import Path
        >>> from snapflow import SamplingMode, SnapFlowPolicy
        >>> from snapflow.policies.checkpoint import policy_metadata, write_policy
        >>> from snapflow.policies.factory import default_config, make_model, make_processor
        >>> from snapflow.policies.normalization import NormalizationStats
        >>> from snapflow.sources import open_policy
        >>> tasks = ["reach"]
        >>> config = default_config("mlp", 3, 2, tasks, hidden_dim=32)  # 3 states, 2 actions
        >>> stats = NormalizationStats([0.0] * 3, [1.0] * 3, [0.0] * 2, [1.0] * 2)
        >>> teacher = SnapFlowPolicy(make_model(config), target_time=False)
        >>> processor = make_processor(config, stats, tasks)
        >>> folder = tempfile.TemporaryDirectory()
        >>> write_policy(Path(folder.name), teacher, policy_metadata(teacher, processor))
        >>> opened = open_policy(folder.name)
        >>> opened.policy_type, opened.distilled
        ('mlp', False)
        >>> opened.resolve_mode(SamplingMode.parse("teacher")).name
        'teacher-10'
        >>> opened.check_mode(SamplingMode.parse("snapflow-1"))  # doctest: +IGNORE_EXCEPTION_DETAIL
        Traceback (most recent call last):
        CheckpointError: ... is not SnapFlow-distilled (a flow-matching teacher) ...
        >>> folder.cleanup()
    """
    text = str(source)
    try:
        folder = local_folder(text)
    except (FileNotFoundError, ValueError) as error:
        raise CheckpointError(str(error)) from None
    for kind in SOURCE_KINDS:
        if kind.recognises(folder):
            return kind.open(text)
    kinds = "; ".join(kind.description for kind in SOURCE_KINDS)
    raise CheckpointError(f"{text} holds no policy snapflow can open; a policy source is {kinds}")


__all__ = [
    "LEROBOT_EXPORT_DIRECTORY",
    "LEROBOT_RUN_FORMAT",
    "SourceKind",
    "SOURCE_KINDS",
    "register_source_kind",
    "open_policy",
    "refuse_lerobot_run",
]
