"""One writer per run folder: an exclusive lock on ``<folder>/.snapflow.lock``, held for the life of a command.

The lock is ``flock``: the kernel releases it when its holder's last descriptor closes, however the process ends
(SIGKILL included), so a dead holder never leaves a stale lock and no pid has to be checked. The file itself stays
after release: deleting it would let one process lock a file that is about to vanish while another locks a new one.
"""

from __future__ import annotations

import fcntl
import json
import os
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from snapflow.errors import SnapflowError

LOCK_FILE = ".snapflow.lock"
_CHOOSE_ANOTHER_OUTPUT = "wait for it to finish or choose another --output"


class RunLockedError(SnapflowError, FileExistsError):
    """The folder is held by another live process (a FileExistsError: the CLI prints it as one line, exit code 2)."""


# folders this process holds -> [descriptor, depth]: a second hold in the same process nests instead of conflicting
# (flock on a second descriptor of the same file would refuse its own process)
_held: dict[Path, list[int]] = {}
_guard = threading.Lock()


def _holder(lock: Path) -> str:
    """``pid N, command`` as the holder wrote it, or what is known when it has not written yet."""
    try:
        holder = json.loads(lock.read_text())
        return f"pid {int(holder['pid'])}, {holder['command']}"
    except (OSError, ValueError, KeyError, TypeError):
        return "pid unknown"


def _acquire(directory: Path, command: str, remedy: str) -> int:
    lock = directory / LOCK_FILE
    descriptor = os.open(lock, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o666)
    try:
        try:
            fcntl.flock(descriptor, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise RunLockedError(
                f"{directory} is in use by another snapflow command ({_holder(lock)}); {remedy}"
            ) from None
        os.ftruncate(descriptor, 0)
        os.pwrite(descriptor, json.dumps({"pid": os.getpid(), "command": command}).encode() + b"\n", 0)
    except BaseException:
        os.close(descriptor)  # refused or failed: hold nothing
        raise
    return descriptor


@contextmanager
def hold_run_lock(directory: str | Path, command: str, remedy: str = _CHOOSE_ANOTHER_OUTPUT) -> Iterator[Path]:
    """Hold ``directory`` (created if missing) for the ``with`` block, or raise :class:`RunLockedError` at once,
    naming the holder's pid and ``command``, and then ``remedy``, when another process holds it.

    Re-entrant within one process: a nested hold of the same folder (``train`` inside ``distill_lerobot``) only nests.
    Yields the directory.
    """
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    key = directory.resolve()
    with _guard:
        if key in _held:
            _held[key][1] += 1
        else:
            _held[key] = [_acquire(directory, command, remedy), 1]
    try:
        yield directory
    finally:
        with _guard:
            _held[key][1] -= 1
            if _held[key][1] == 0:
                os.close(_held.pop(key)[0])  # releases the lock


def held_since(directory: str | Path) -> float | None:
    """When the live process that holds ``directory`` took it (a time stamp: its holder writes the lock file as it
    takes it), or None where none holds it."""
    return (Path(directory) / LOCK_FILE).stat().st_mtime if lock_holder(directory) is not None else None


def lock_holder(directory: str | Path) -> str | None:
    """Who holds ``directory`` (``pid N, command``), or None where no live process does: a look that takes nothing
    (a shared lock tried and let go at once)."""
    lock = Path(directory) / LOCK_FILE
    if Path(directory).resolve() in _held:
        return f"pid {os.getpid()}, this process"
    try:
        descriptor = os.open(lock, os.O_RDONLY | os.O_CLOEXEC)
    except FileNotFoundError:
        return None
    try:
        fcntl.flock(descriptor, fcntl.LOCK_SH | fcntl.LOCK_NB)
    except BlockingIOError:
        return _holder(lock)
    finally:
        os.close(descriptor)  # releases the shared lock if it was taken
    return None


__all__ = ["LOCK_FILE", "RunLockedError", "held_since", "hold_run_lock", "lock_holder"]
