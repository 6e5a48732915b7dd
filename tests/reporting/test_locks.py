"""One writer per run folder: a folder held by a live process is refused to every other, naming the holder, and is
free the moment its holder dies, SIGKILL included. Real processes, real files."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys

import pytest

from snapflow.reporting.locks import LOCK_FILE, RunLockedError, hold_run_lock
from tests.locking import held_by_another_process

PROBE = """
import sys
from snapflow.reporting.locks import RunLockedError, hold_run_lock

try:
    with hold_run_lock(sys.argv[1], "probe"):
        pass
except RunLockedError:
    sys.exit(3)
"""


def _another_process_can_hold(directory) -> bool:
    probe = subprocess.run([sys.executable, "-c", PROBE, str(directory)], capture_output=True, text=True, timeout=60)
    assert probe.returncode in (0, 3), probe.stderr
    return probe.returncode == 0


def test_a_held_folder_is_refused_naming_its_holder_and_is_free_at_once_when_the_holder_is_killed(tmp_path):
    run = tmp_path / "runs" / "x"  # created by the holder
    with held_by_another_process(run, "snapflow distill") as holder:
        with pytest.raises(RunLockedError) as refused:
            with hold_run_lock(run, "snapflow train"):
                pytest.fail("a folder was held by two processes at once")
        assert str(refused.value) == (
            f"{run} is in use by another snapflow command (pid {holder.pid}, snapflow distill); "
            "wait for it to finish or choose another --output"
        )
        assert isinstance(refused.value, FileExistsError), "the CLI prints FileExistsError as one line, exit code 2"
        holder.kill()  # SIGKILL: the holder releases nothing itself
        assert holder.wait() == -signal.SIGKILL
        with hold_run_lock(run, "snapflow train"):  # at once: no stale lock, no waiting, no pid to check
            assert json.loads((run / LOCK_FILE).read_text()) == {"pid": os.getpid(), "command": "snapflow train"}
            assert not _another_process_can_hold(run)
    assert (run / LOCK_FILE).is_file(), "the lock file stays behind: deleting it would race with the next holder"
    assert _another_process_can_hold(run)


def test_a_hold_nests_within_one_process_and_ends_with_the_outermost(tmp_path):
    run = tmp_path / "run"
    with hold_run_lock(run, "snapflow distill"):
        with hold_run_lock(tmp_path / "." / "run", "snapflow distill"):  # as train() inside distill_lerobot
            assert not _another_process_can_hold(run)
        assert not _another_process_can_hold(run), "the inner hold's end must not release the outer one"
    assert _another_process_can_hold(run)
