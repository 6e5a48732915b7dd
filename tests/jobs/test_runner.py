"""The job runner on jobs that only write logs: its order, interrupted, failed and killed jobs, a fresh process and
the threads asked for each job."""

from __future__ import annotations

import os
import signal
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

import pytest
import torch

from snapflow.errors import SnapflowError
from snapflow.jobs.runner import Job, is_done, read_record, run_jobs, to_run


@dataclass(frozen=True)
class LogJob(Job):
    """Appends a line to its log; ``fail`` (not a setting) makes it fail after writing, as an interrupted run."""

    kind: ClassVar[str] = "log"
    directory: Path
    value: int
    fail: bool = False

    def settings(self) -> dict[str, Any]:
        return {"value": self.value}

    @property
    def record_path(self) -> Path:
        return self.directory / "job.json"

    @property
    def outputs(self) -> tuple[Path, ...]:
        return (self.directory,)

    def run(self) -> dict[str, Any]:
        with open(self.directory / "log.txt", "a") as log:
            log.write(f"{self.value}\n")
        if self.fail:
            raise RuntimeError("the job failed on purpose")
        lines = len((self.directory / "log.txt").read_text().splitlines())
        return {"lines": lines, "process": os.getpid(), "threads": torch.get_num_threads()}

    def describe(self) -> str:
        return f"log {self.value}"


@dataclass(frozen=True)
class StageJob(LogJob):
    """A log job that reads others' outputs."""

    needs: tuple[Job, ...] = ()

    @property
    def dependencies(self) -> tuple[Job, ...]:
        return self.needs


def test_a_teachers_evaluation_runs_before_its_students_training(tmp_path):
    teacher = StageJob(tmp_path / "teacher", 0)
    student = StageJob(tmp_path / "student", 1, needs=(teacher,))
    student_eval = StageJob(tmp_path / "student-eval", 2, needs=(student,))
    teacher_eval = StageJob(tmp_path / "teacher-eval", 3, needs=(teacher,))
    assert to_run([student_eval, teacher_eval]) == [teacher, teacher_eval, student, student_eval]


@pytest.mark.slow
def test_a_ready_evaluation_runs_before_a_teacher_that_waits_at_a_lower_depth(tmp_path):
    """One worker, two teachers and their evaluations: to_run's order trains both teachers first (depth), but once
    the first is trained its evaluation, ready and needed by nothing, runs before the second teacher starts."""
    first, second = StageJob(tmp_path / "first", 0), StageJob(tmp_path / "second", 1)
    first_eval = StageJob(tmp_path / "first-eval", 2, needs=(first,))
    second_eval = StageJob(tmp_path / "second-eval", 3, needs=(second,))
    assert to_run([first_eval, second_eval]) == [first, second, first_eval, second_eval]
    finished = list(run_jobs([first_eval, second_eval], workers=1, progress=False))
    assert finished == ["log 0", "log 2", "log 1", "log 3"]


@pytest.mark.slow
def test_the_runner_continues_an_interrupted_job_and_restarts_a_stale_one(tmp_path):
    directory = tmp_path / "job"
    with pytest.raises(RuntimeError, match="failed on purpose"):  # a failed job stops the run with its own error
        run_jobs([LogJob(directory, 1, fail=True)], progress=False)
    assert not is_done(LogJob(directory, 1))
    assert set(run_jobs([LogJob(directory, 1)], progress=False)) == {"log 1"}
    record = read_record(LogJob(directory, 1))
    assert (record["config"], record["lines"]) == ({"value": 1}, 2), "same settings: its outputs were kept"
    assert run_jobs([LogJob(directory, 1)], progress=False) == {}
    run_jobs([LogJob(directory, 2)], progress=False)
    assert read_record(LogJob(directory, 2))["lines"] == 1, "other settings: its old outputs were cleared first"
    assert not is_done(LogJob(directory, 1))


@dataclass(frozen=True)
class SlowJob(LogJob):
    """A log job that takes a few seconds, long enough for another worker's job to fail first."""

    def run(self) -> dict[str, Any]:
        time.sleep(3)
        return super().run()


@pytest.mark.slow
def test_a_failed_job_stops_the_run_once_the_jobs_running_beside_it_have_finished_and_been_recorded(tmp_path):
    failing, running, later = (
        LogJob(tmp_path / "fails", 1, fail=True),
        SlowJob(tmp_path / "slow", 2),
        LogJob(tmp_path / "later", 3),
    )
    with pytest.raises(RuntimeError, match="failed on purpose"):
        run_jobs([failing, running, later], workers=2, progress=False)
    assert is_done(running), "what finished beside the failure is recorded: the same command does not run it again"
    assert not is_done(failing) and not (tmp_path / "later").exists(), "no job starts after a failure"


@dataclass(frozen=True)
class KilledJob(LogJob):
    """A log job whose worker is killed as it runs, as the system kills one out of memory."""

    def run(self) -> dict[str, Any]:
        super().run()
        os.kill(os.getpid(), signal.SIGKILL)
        return {}


def test_a_killed_worker_stops_the_run_naming_its_job_and_the_same_command_goes_on(tmp_path):
    directory = tmp_path / "job"
    with pytest.raises(SnapflowError, match=r"the worker running log 1 died \(killed, or out of memory\)"):
        run_jobs([KilledJob(directory, 1)], progress=False)
    assert not is_done(LogJob(directory, 1))
    run_jobs([LogJob(directory, 1)], progress=False)
    assert read_record(LogJob(directory, 1))["lines"] == 2, "its pending run's outputs were kept and went on"


@pytest.mark.slow
def test_every_job_runs_in_a_fresh_process_so_its_memory_goes_with_it(tmp_path):
    jobs = [LogJob(tmp_path / f"job-{value}", value) for value in range(3)]
    run_jobs(jobs, workers=1, progress=False)
    processes = {read_record(job)["process"] for job in jobs}
    assert len(processes) == 3 and os.getpid() not in processes
    assert {read_record(job)["threads"] for job in jobs} == {os.cpu_count()}, "one worker: every core's thread"


@pytest.mark.slow
def test_a_job_runs_on_the_threads_asked_for_where_other_programs_share_the_cores(tmp_path):
    job = LogJob(tmp_path / "job", 0)
    run_jobs([job], workers=1, progress=False, threads=1)
    assert read_record(job)["threads"] == 1
