"""Weights kept in the repository's history instead of its tree.

A checkpoint that a committed result or a sweep's resume needs is too large to travel with every clone, and must still
survive a change of machine with main alone. So :func:`archive` commits such files once and removes them from the
tree in the next commit; the tracked manifest (:data:`MANIFEST`) names for each file its path, the commit that holds
it and its git blob id. :func:`restore` writes them back where they were, byte for byte (a partial clone,
``git clone --filter=blob:none``, fetches each blob only then), so the sweep runner and ``open_policy`` find them where
they found them before. The same holds for a sweep's collected demonstrations, kept packed (one tar a task,
:mod:`snapflow.reporting.packed`). Archived files are git-ignored (:data:`ARCHIVED_GLOBS` in ``.gitignore``), so a
restored or newly written checkpoint never travels with the working tree by accident. History is never rewritten.
"""

from __future__ import annotations

import hashlib
import json
import os
import subprocess
import tempfile
from collections.abc import Iterable, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path, PurePosixPath

from snapflow.errors import InvalidInputError
from snapflow.reporting.files import atomic_write, write_json

MANIFEST = PurePosixPath("docs/results/archive.json")  # relative to the repository's root
ARCHIVED_ROOT = PurePosixPath("docs/results")  # where the files that are archived live
# which files there are archived: every weight and optimizer state, and every packed folder (a task's demonstrations)
ARCHIVED_GLOBS = ("*.safetensors", "*.tar")
RESTORE_COMMAND = "snapflow checkpoints restore"


class ArchiveError(InvalidInputError):
    """The archive cannot do what was asked: not a git checkout, a manifest that is corrupt, a commit not in this
    clone. The message says what to do."""


@dataclass(frozen=True)
class ArchivedFile:
    """One file of the archive: where it goes, the commit whose tree holds it, its git blob id and size."""

    path: str  # relative to the repository's root, with forward slashes
    commit: str
    blob: str
    bytes: int


def git_blob_id(data: bytes) -> str:
    """The id git gives ``data`` as a blob (SHA-1 of its header and content): what a restored file is checked
    against."""
    return hashlib.sha1(b"blob %d\0" % len(data) + data).hexdigest()


def repository_root(start: str | Path = ".") -> Path:
    """The root of the git checkout that holds ``start``."""
    result = _git(Path(start) if Path(start).is_dir() else Path(start).parent, "rev-parse", "--show-toplevel")
    return Path(result.decode().strip())


def read_manifest(root: Path) -> list[ArchivedFile]:
    """The manifest's entries (none where it does not exist yet)."""
    path = root / MANIFEST
    if not path.is_file():
        return []
    try:
        return [ArchivedFile(**entry) for entry in json.loads(path.read_text())["files"]]
    except (json.JSONDecodeError, KeyError, TypeError) as error:
        raise ArchiveError(f"{path} is corrupt ({error}): restore it with git checkout -- {MANIFEST}") from None


def write_manifest(root: Path, files: Iterable[ArchivedFile]) -> Path:
    entries = sorted(files, key=lambda entry: entry.path)
    return write_json(
        root / MANIFEST,
        {
            "about": f"checkpoints kept in main's history, not its tree; `{RESTORE_COMMAND} [PATH ...]` writes them back",
            "files": [asdict(entry) for entry in entries],
        },
    )


def select(files: Sequence[ArchivedFile], prefixes: Sequence[str]) -> list[ArchivedFile]:
    """The entries at or under any of ``prefixes`` (paths relative to the root; all entries where none is given)."""
    if not prefixes:
        return list(files)
    wanted = [PurePosixPath(prefix.rstrip("/")) for prefix in prefixes]
    chosen = [entry for entry in files if any(_under(PurePosixPath(entry.path), prefix) for prefix in wanted)]
    missing = [str(prefix) for prefix in wanted if not any(_under(PurePosixPath(e.path), prefix) for e in files)]
    if missing:
        raise ArchiveError(f"nothing archived at or under {', '.join(missing)} (see `snapflow checkpoints list`)")
    return chosen


def is_present(root: Path, entry: ArchivedFile) -> bool:
    """Whether the file is in place under ``root`` with the archived content."""
    path = root / entry.path
    return path.is_file() and path.stat().st_size == entry.bytes and git_blob_id(path.read_bytes()) == entry.blob


def restore(root: Path, entries: Sequence[ArchivedFile], into: Path | None = None) -> list[ArchivedFile]:
    """Write each entry's file back from the history of the checkout at ``root`` where it is missing or differs, at
    its path under ``into`` (default: ``root``); those written. Each file appears whole or not at all, checked
    against its blob id."""
    into = root if into is None else into
    written = []
    for entry in entries:
        if is_present(into, entry):
            continue
        try:
            data = _git(root, "cat-file", "blob", f"{entry.commit}:{entry.path}")
        except ArchiveError as error:
            raise ArchiveError(
                f"cannot read {entry.path} from commit {entry.commit[:12]} ({error}); it is in main's history: in a "
                "shallow clone run `git fetch --unshallow` first"
            ) from None
        if git_blob_id(data) != entry.blob:
            raise ArchiveError(f"{entry.path} at commit {entry.commit[:12]} is not the archived blob {entry.blob[:12]}")
        atomic_write(into / entry.path, lambda temporary, data=data: temporary.write_bytes(data))
        written.append(entry)
    return written


def pending(root: Path) -> list[str]:
    """The files under :data:`ARCHIVED_ROOT` matching :data:`ARCHIVED_GLOBS` that the manifest lacks or names with
    other content: tracked ones (committed before the archive existed) and ignored ones (written since)."""
    pathspecs = [f":(glob){ARCHIVED_ROOT}/**/{pattern}" for pattern in ARCHIVED_GLOBS]
    tracked = _git(root, "ls-files", "-z", "--", *pathspecs)
    ignored = _git(root, "ls-files", "-z", "--others", "--ignored", "--exclude-standard", "--", *pathspecs)
    known = {entry.path: entry for entry in read_manifest(root)}
    paths = sorted({path for path in (tracked + ignored).decode().split("\0") if path})
    return [path for path in paths if path not in known or not is_present(root, known[path])]


@dataclass(frozen=True)
class Archived:
    """What :func:`archive` did: the commit holding the files, the one taking them out of the tree, and the manifest
    entries it dropped as superseded."""

    added: str
    removed: str
    superseded: tuple[str, ...]


def archive(root: Path, paths: Sequence[str], message: str) -> Archived:
    """Commit ``paths`` (files under ``root``) into the current branch, then a second commit that removes them from
    the tree and names that first commit in the manifest; the files stay on disk. Neither commit touches the index
    or any other change in the working tree (each is built on a temporary index).

    An entry whose folder the working tree no longer holds is dropped from the manifest as superseded: a run's kept
    progress moved on to a later checkpoint folder (every kept folder holds small tracked files beside its weights,
    so a fresh clone has each folder the manifest names). Its weights stay in history at the commit it named."""
    if not paths:
        raise ArchiveError("nothing to archive")
    blobs = {path: _git(root, "hash-object", "-w", "--", path).decode().strip() for path in paths}
    head = _git(root, "rev-parse", "HEAD").decode().strip()
    if all(_blob_at(root, head, path) == blob for path, blob in blobs.items()):
        added = head  # committed before the archive existed: HEAD already holds them
    else:
        listing = "".join(f"  {path}\n" for path in paths)
        added = _commit(root, head, f"{message}\n\nInto history, out of the tree in the next commit:\n{listing}", blobs)
    entries = {entry.path: entry for entry in read_manifest(root)}
    superseded = tuple(path for path in entries if not (root / path).parent.is_dir())
    for path in superseded:
        del entries[path]
    for path, blob in blobs.items():
        entries[path] = ArchivedFile(path, added, blob, (root / path).stat().st_size)
    write_manifest(root, entries.values())
    manifest_blob = _git(root, "hash-object", "-w", "--", str(MANIFEST)).decode().strip()
    removed = _commit(
        root,
        added,
        f"{message}: out of the tree; {MANIFEST} names commit {added[:12]} (`{RESTORE_COMMAND}` brings them back)",
        add={str(MANIFEST): manifest_blob},
        remove=paths,
    )
    _git(root, "update-ref", "-m", "snapflow checkpoints archive", "HEAD", removed, head)  # fails if HEAD moved
    _git(root, "add", "--", str(MANIFEST))  # the index now agrees with the new HEAD on the manifest
    _git(root, "rm", "-q", "--cached", "--ignore-unmatch", "--", *paths)  # and no longer tracks the files
    return Archived(added, removed, superseded)


def _in_checkout(path: str | Path) -> tuple[Path, PurePosixPath] | None:
    """The root of the nearest checkout above ``path`` that has a manifest, and ``path`` relative to it; None where
    no folder above it has one."""
    path = Path(path).resolve()
    root = next((folder for folder in path.parents if (folder / MANIFEST).is_file()), None)
    return None if root is None else (root, PurePosixPath(path.relative_to(root).as_posix()))


def restore_if_archived(path: str | Path) -> bool:
    """Bring ``path`` (a file) back from the history of the checkout that holds it where it is missing and the
    manifest names it: what a sweep does for the packed demonstrations it needs. False where it is not archived (or
    not in a checkout)."""
    found = _in_checkout(path)
    if found is None:
        return False
    root, relative = found
    entries = [entry for entry in read_manifest(root) if entry.path == str(relative)]
    return bool(entries) and (bool(restore(root, entries)) or is_present(root, entries[0]))


def archived_hint(path: str | Path) -> str:
    """Where ``path`` (a missing file, or a folder missing files) is archived: the command that restores it, else
    an empty string."""
    found = _in_checkout(path)
    if found is None:
        return ""
    root, relative = found
    try:
        entries = read_manifest(root)
    except ArchiveError:
        return ""
    if any(_under(PurePosixPath(entry.path), relative) for entry in entries):
        return f"; it is archived in git history: `{RESTORE_COMMAND} {relative}` brings it back"
    return ""


def _blob_at(root: Path, commit: str, path: str) -> str | None:
    try:
        return _git(root, "rev-parse", "--verify", "-q", f"{commit}:{path}").decode().strip()
    except ArchiveError:
        return None


def _under(path: PurePosixPath, prefix: PurePosixPath) -> bool:
    return path == prefix or prefix in path.parents


def _commit(root: Path, parent: str, message: str, add: dict[str, str], remove: Sequence[str] = ()) -> str:
    """A commit on ``parent``'s tree with ``add`` (path -> blob) added and ``remove`` removed, built on a temporary
    index so that the real one and the working tree stay as they are."""
    with tempfile.TemporaryDirectory() as scratch:
        environment = {**os.environ, "GIT_INDEX_FILE": str(Path(scratch) / "index")}
        _git(root, "read-tree", parent, environment=environment)
        if remove:
            _git(root, "update-index", "--force-remove", "--", *remove, environment=environment)
        for path, blob in add.items():
            _git(root, "update-index", "--add", "--cacheinfo", f"100644,{blob},{path}", environment=environment)
        tree = _git(root, "write-tree", environment=environment).decode().strip()
    return _git(root, "commit-tree", tree, "-p", parent, "-m", message).decode().strip()


def _git(root: Path, *arguments: str, environment: dict[str, str] | None = None) -> bytes:
    try:
        result = subprocess.run(["git", *arguments], cwd=root, capture_output=True, env=environment, check=False)
    except FileNotFoundError:
        raise ArchiveError("git is not installed") from None
    if result.returncode != 0:
        raise ArchiveError(result.stderr.decode(errors="replace").strip() or f"git {arguments[0]} failed")
    return result.stdout


__all__ = [
    "Archived",
    "MANIFEST",
    "ARCHIVED_ROOT",
    "ARCHIVED_GLOBS",
    "RESTORE_COMMAND",
    "ArchiveError",
    "ArchivedFile",
    "git_blob_id",
    "repository_root",
    "read_manifest",
    "write_manifest",
    "select",
    "is_present",
    "restore",
    "pending",
    "archive",
    "restore_if_archived",
    "archived_hint",
]
