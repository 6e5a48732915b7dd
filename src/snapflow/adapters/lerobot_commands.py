"""LeRobot's own commands (``lerobot-train``, ``lerobot-eval``) run as subprocesses of this interpreter's
environment, the way every caller in snapflow runs them: offline, on the torch threads asked for, their output in a
log file, and a failure told as a :class:`~snapflow.errors.SnapflowError` ending with the log's tail. Plain Python:
importing it loads neither torch nor LeRobot."""

from __future__ import annotations

import os
import subprocess
from pathlib import Path

from snapflow.errors import SnapflowError

#: how much of a failed command's log its error repeats
LOG_TAIL_CHARACTERS = 3000


def run_lerobot_command(
    name: str,
    command: list[str],
    log: str | Path,
    threads: int | None = None,
    append: bool = False,
    directory: str | Path | None = None,
) -> None:
    """Run ``command`` (LeRobot's command ``name``, for the error) with ``HF_HUB_OFFLINE`` set and, where ``threads``
    is given, ``OMP_NUM_THREADS``; stdout and stderr go to ``log`` (its folder made; ``append``: after the lines a
    previous run left, as a resumed run's do); in the working directory ``directory`` (default: this one). A non-zero
    exit raises a :class:`SnapflowError` with the log's tail."""
    log = Path(log)
    log.parent.mkdir(parents=True, exist_ok=True)
    environment = {**os.environ, "HF_HUB_OFFLINE": "1", **({"OMP_NUM_THREADS": str(threads)} if threads else {})}
    with log.open("a" if append else "w") as written:
        status = subprocess.run(
            command, env=environment, cwd=directory, stdin=subprocess.DEVNULL, stdout=written, stderr=subprocess.STDOUT
        ).returncode
    if status != 0:
        raise SnapflowError(
            f"{name} exited {status}; its output is in {log}, ending:\n{log.read_text()[-LOG_TAIL_CHARACTERS:]}"
        )


__all__ = ["LOG_TAIL_CHARACTERS", "run_lerobot_command"]
