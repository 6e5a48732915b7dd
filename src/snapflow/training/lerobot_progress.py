"""A ``lerobot-train`` run's progress kept where it can be committed, and put back on another machine.

lerobot-train saves a checkpoint (``checkpoints/<step>/``: the policy folder and its training state) every
``save_freq`` steps, then points ``checkpoints/last`` at it, and resumes from ``last`` where its run folder is still
there. A machine's end takes the run folder with it. :class:`CheckpointKeeper` copies each checkpoint marked last into
a kept folder as it appears (the previous copy removed only once the new one is whole), and
:func:`install_kept_progress` puts the kept one back into an empty run folder, so that lerobot-train resumes from it
on any clone. The student folder's absolute path, which its config names (a local VLM), is kept as a placeholder: a
kept file names no path of the machine that wrote it. lerobot-train records no time across its attempts: each
checkpoint is stamped with the run's training time up to it (:data:`ELAPSED`), from which a resumed attempt counts on,
so that a run's recorded time is its whole training's, however many machines it took."""

from __future__ import annotations

import json
import os
import threading
import time
from pathlib import Path
from types import TracebackType
from typing import Any

from snapflow.reporting.files import write_json
from snapflow.training.checkpoint import STEP_PREFIX, copy_checkpoint, keep_checkpoint, read_kept

#: what stands for the student folder's absolute path in a kept checkpoint's files
STUDENT_FOLDER = "${STUDENT_FOLDER}"
#: how often a running lerobot-train's ``checkpoints/last`` is looked at, in seconds
POLL_SECONDS = 5.0
#: a checkpoint's training time so far, in its ``training_state/`` (LeRobot reads only its own files there)
ELAPSED = "snapflow_elapsed.json"


def newest_checkpoint(output: Path) -> Path | None:
    """The checkpoint lerobot-train's run folder ``output`` marks last (whole: it marks one once saved), or None."""
    last = Path(output) / "checkpoints" / "last"
    try:
        checkpoint = last.parent / os.readlink(last)
    except OSError:  # none yet, or being pointed at the next one this instant
        return None
    return checkpoint if (checkpoint / "training_state").is_dir() else None


def _saved_at(checkpoint: Path) -> float:
    """When lerobot-train saved ``checkpoint`` (its step file's modification time)."""
    return (Path(checkpoint) / "training_state" / "training_step.json").stat().st_mtime


def _stamp(checkpoint: Path) -> float | None:
    path = Path(checkpoint) / "training_state" / ELAPSED
    return json.loads(path.read_text())["seconds"] if path.is_file() else None


def elapsed_at(checkpoint: Path | None) -> float:
    """The training time, in seconds, of the run up to ``checkpoint``: its stamp; where it has none (its attempt was
    cut before stamping it), the newest stamped checkpoint saved before it plus the time between their savings; 0
    where there is none, or none is stamped (saved before checkpoints were stamped: its time unknown)."""
    if checkpoint is None:
        return 0.0
    if (seconds := _stamp(checkpoint)) is not None:
        return seconds
    saved = _saved_at(checkpoint)
    stamped = [
        (_saved_at(other), stamp)
        for other in Path(checkpoint).parent.iterdir()
        if other.is_dir() and not other.is_symlink() and (stamp := _stamp(other)) is not None
    ]
    earlier = [(stamped_at, stamp) for stamped_at, stamp in stamped if stamped_at <= saved]
    if not earlier:
        return 0.0
    stamped_at, stamp = max(earlier)
    return stamp + saved - stamped_at


def keep_lerobot_checkpoint(checkpoint: Path, kept: Path, student: Path, run: dict[str, Any]) -> Path:
    """Make ``checkpoint`` (``checkpoints/<step>``) the one kept in ``kept``, noted as the progress of ``run`` (what
    the run is: only a run of the same resumes from it), ``student``'s path a placeholder."""
    absolute = str(Path(student).resolve())
    return keep_checkpoint(
        checkpoint,
        kept,
        {"run": run},
        prepare=lambda copy: _replace_in_json(copy, absolute, STUDENT_FOLDER),
        name=f"{STEP_PREFIX}{Path(checkpoint).name}",
    )


def install_kept_progress(kept: Path, output: Path, student: Path, run: dict[str, Any]) -> bool:
    """Put the checkpoint kept in ``kept`` into lerobot-train's run folder ``output`` (which holds none) as its last,
    naming ``student`` where the placeholder stands; False where ``kept`` holds no progress of ``run`` (nothing, a
    finished run's policy, or another run's progress, which the new run's checkpoints then replace)."""
    found = read_kept(Path(kept))
    if found is None or found[1] != {"run": run} or not found[0].name.startswith(STEP_PREFIX):
        return False
    step = found[0].name.removeprefix(STEP_PREFIX)
    installed = copy_checkpoint(found[0], Path(output) / "checkpoints" / step)
    _replace_in_json(installed, STUDENT_FOLDER, str(Path(student).resolve()))
    (installed.parent / "last").symlink_to(step)
    return True


class CheckpointKeeper:
    """While a lerobot-train attempt writes into ``output``, stamp each checkpoint it marks last with the run's
    training time up to it and, where ``kept`` is given, keep it there (looked for every :data:`POLL_SECONDS`) as
    the progress of ``run``; the last one once more as the attempt stops. :attr:`elapsed` is the run's training
    time: the checkpoint it resumed from, then this attempt's. An error in keeping is raised on exit."""

    def __init__(self, output: Path, kept: Path | None, student: Path, run: dict[str, Any]) -> None:
        self.output, self.student, self.run = Path(output), Path(student), run
        self.kept = Path(kept) if kept is not None else None
        self.began = time.time()  # wall clock: a checkpoint's time is read from its files' modification times
        self.before = elapsed_at(newest_checkpoint(self.output))
        found = read_kept(self.kept) if self.kept is not None else None
        self._kept_step = found[0].name.removeprefix(STEP_PREFIX) if found and found[1] == {"run": run} else None
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._watch, name="lerobot-train checkpoint keeper", daemon=True)
        self._error: BaseException | None = None

    @property
    def elapsed(self) -> float:
        """The run's training time so far, in seconds."""
        return self.before + time.time() - self.began

    def keep_newest(self) -> None:
        """Stamp the checkpoint marked last, and keep it, where it is not the one kept already."""
        newest = newest_checkpoint(self.output)
        if newest is None or newest.name == self._kept_step:
            return
        if _stamp(newest) is None:
            saved = _saved_at(newest)
            # saved by this attempt: its time is this one's; by an earlier one cut before stamping it: read off others
            # (a file's time comes from a coarser clock than time.time(): a second's slack)
            this_attempt = saved >= self.began - 1.0
            seconds = self.before + max(saved - self.began, 0.0) if this_attempt else elapsed_at(newest)
            write_json(newest / "training_state" / ELAPSED, {"seconds": seconds})
        if self.kept is not None:
            keep_lerobot_checkpoint(newest, self.kept, self.student, self.run)
        self._kept_step = newest.name

    def _watch(self) -> None:
        try:
            while not self._stop.wait(POLL_SECONDS):
                self.keep_newest()
        except BaseException as error:  # raised in the main thread on exit, not lost with this one
            self._error = error

    def __enter__(self) -> CheckpointKeeper:
        self._thread.start()
        return self

    def __exit__(
        self, kind: type[BaseException] | None, error: BaseException | None, traceback: TracebackType | None
    ) -> None:
        self._stop.set()
        self._thread.join()
        if self._error is not None:
            raise self._error
        self.keep_newest()


def _replace_in_json(folder: Path, old: str, new: str) -> None:
    """Replace ``old`` by ``new`` in every JSON file under ``folder`` (a path as JSON writes it: no escaping)."""
    for path in Path(folder).rglob("*.json"):
        text = path.read_text()
        if old in text:
            path.write_text(text.replace(old, new))


__all__ = [
    "STUDENT_FOLDER",
    "ELAPSED",
    "CheckpointKeeper",
    "elapsed_at",
    "install_kept_progress",
    "keep_lerobot_checkpoint",
    "newest_checkpoint",
]
