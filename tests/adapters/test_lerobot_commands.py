"""How snapflow runs LeRobot's own commands (``run_lerobot_command``): offline, on the threads asked for, into a log,
and a failure as one named error with the log's tail. A real subprocess (this interpreter) stands in for LeRobot's."""

from __future__ import annotations

import sys

import pytest

from snapflow.adapters.lerobot_commands import run_lerobot_command
from snapflow.errors import SnapflowError

PRINT_ENVIRONMENT = "import os; print(os.environ['HF_HUB_OFFLINE'], os.environ.get('OMP_NUM_THREADS'))"


def test_a_command_runs_offline_on_the_threads_asked_for_into_its_log(tmp_path):
    log = tmp_path / "runs" / "train.log"
    run_lerobot_command("lerobot-train", [sys.executable, "-c", PRINT_ENVIRONMENT], log, threads=3)
    run_lerobot_command("lerobot-train", [sys.executable, "-c", PRINT_ENVIRONMENT], log, threads=2, append=True)
    assert log.read_text().splitlines() == ["1 3", "1 2"], "a resumed run's lines follow the first run's"
    run_lerobot_command("lerobot-eval", [sys.executable, "-c", "print('again')"], log)
    assert log.read_text() == "again\n", "without append, a new log"


def test_a_failed_command_is_named_with_its_exit_status_and_the_end_of_its_log(tmp_path):
    log = tmp_path / "eval.log"
    failing = [sys.executable, "-c", "import sys; print('x' * 5000); print('the cause'); sys.exit(3)"]
    with pytest.raises(SnapflowError, match=r"(?s)^lerobot-eval exited 3; its output is in .*eval\.log.*the cause\n$"):
        run_lerobot_command("lerobot-eval", failing, log)
