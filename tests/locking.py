"""A run folder held by another live process, as a concurrent snapflow command holds it (for the lock tests)."""

from __future__ import annotations

import subprocess
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

HOLD = """
import sys, time
from snapflow.reporting.locks import hold_run_lock

with hold_run_lock(sys.argv[1], sys.argv[2]):
    print("held", flush=True)
    time.sleep(600)
"""


@contextmanager
def held_by_another_process(directory: Path, command: str = "snapflow train") -> Iterator[subprocess.Popen]:
    """``directory`` held by a child process that names itself ``command``, for the ``with`` block (SIGKILLed at its
    end, if the block has not done so); yields the child."""
    holder = subprocess.Popen([sys.executable, "-c", HOLD, str(directory), command], stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline() == "held\n", "the holder did not start"
        yield holder
    finally:
        holder.kill()
        holder.wait()
        holder.stdout.close()
