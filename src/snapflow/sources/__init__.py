"""What is at a path: :func:`open_policy` opens a built-in checkpoint, a LeRobot folder or hub id, or an export of
either, as one :class:`~snapflow.policies.loaded.OpenedPolicy`; the kinds it recognises are registered here, in one
place, in the order they are tried."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from snapflow import install_command
from snapflow._lazy import resolve
from snapflow.adapters.hub import check_source, local_folder
from snapflow.policies.checkpoint import is_builtin_checkpoint
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


def register_source_kind(kind: SourceKind) -> None:
    """Add a kind of policy source, tried after those registered before it."""
    if any(known.name == kind.name for known in SOURCE_KINDS):
        raise ValueError(f"a source kind named {kind.name!r} is registered already")
    SOURCE_KINDS.append(kind)


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
    is named as such, never looked up on the hub."""
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


__all__ = ["SourceKind", "SOURCE_KINDS", "register_source_kind", "open_policy"]
