"""One job runner for the sweeps and the toy comparison: typed jobs, one cache rule, one loop over a backend
(:mod:`snapflow.jobs.backends`: processes on this machine, or tasks on a Ray cluster).

A job is a frozen dataclass. Its ``settings()`` are every value its result depends on (defaults included), its
``key`` hashes its kind, settings and dependencies' keys, so a key changes whenever anything upstream changes.

The cache rule: when a job has finished, the runner writes its *record*, ``{"config": settings, "dependencies":
[keys], **what run() returned}`` (``dependencies`` only when it has some), atomically to ``job.record_path``. A job
is done iff its record holds its current settings and its dependencies' current keys; anything else runs again,
from scratch: its outputs are removed first, unless a *pending* record (written when it was started) shows an
interrupted run with the same settings, which it then continues (trainers resume their checkpoints).

A job may also keep its record in a *ledger* (``ledger_path``), a copy kept where it can be committed beside the
results (a sweep's, under its results folder). A fresh machine then knows the result without the outputs: a job
recorded there is not run again unless a job that does run needs its outputs (a student's teacher, the data an
evaluation reads). So a long sweep's finished evaluations, committed as they arrive, are not repeated.

A job may keep beside its ledger record what a later machine needs to go on without repeating it: its outputs once
it has finished (a trained policy), which :meth:`Job.restore_outputs` brings back when a job that runs needs them,
and its progress while it runs (a training checkpoint), which :meth:`Job.restore_progress` brings back when it is
started again, so that it continues where the other machine stopped.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
from abc import ABC, abstractmethod
from collections.abc import Iterable
from concurrent.futures import FIRST_COMPLETED, Future, wait
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

from tqdm.auto import tqdm

from snapflow.errors import InvalidInputError, SnapflowError
from snapflow.jobs.backends import Backend, LocalBackend, WorkerDied
from snapflow.reporting.files import write_json
from snapflow.reporting.machine import versions


@dataclass(frozen=True)
class JobProgress:
    """How far an unfinished run of a job has come: ``done`` of its ``total`` ``unit`` (steps, episodes)."""

    done: int
    total: int
    unit: str

    @property
    def share(self) -> float:
        """The share of its work done, from 0 to 1."""
        return min(self.done / self.total, 1.0) if self.total > 0 else 0.0


class Job(ABC):
    """A unit of work with cached output; subclasses are frozen dataclasses (hashable, picklable to workers)."""

    kind: ClassVar[str]
    #: whether the job runs a policy (trains or evaluates one), which a GPU speeds up: a backend that reserves
    #: resources for each job (Ray) gives GPUs to these only
    uses_gpu: ClassVar[bool] = False

    @abstractmethod
    def settings(self) -> dict[str, Any]:
        """The full resolved settings (JSON-able): every field of every dataclass involved, defaults included."""

    @property
    def dependencies(self) -> tuple[Job, ...]:
        """Jobs whose outputs this one reads; they run first, and their keys are part of this job's."""
        return ()

    @property
    @abstractmethod
    def record_path(self) -> Path:
        """Where the runner writes the record of the finished job."""

    @property
    def outputs(self) -> tuple[Path, ...]:
        """Files and folders removed before the job runs again (its record is always removed)."""
        return ()

    @property
    def ledger_path(self) -> Path | None:
        """Where a copy of the record is kept to be committed (None: nowhere)."""
        return None

    def reads_outputs_of(self, dependency: Job) -> bool:
        """Whether running this job reads ``dependency``'s outputs (default: every dependency's). One it does not read
        is part of its key only, and is not brought back to run it."""
        return True

    def restore_outputs(self) -> bool:
        """Rebuild the outputs of this job, recorded in its ledger, from what its run on another machine kept there;
        False where nothing was kept (the default), and the job then runs again."""
        return False

    def restore_progress(self) -> bool:
        """Put the progress that an unfinished run of this job with its current settings kept on another machine into
        its (empty) outputs, to be continued; False where nothing was kept (the default)."""
        return False

    def progress(self) -> JobProgress | None:
        """How far a started, unfinished run of this job with its current settings has come, here or in the progress
        it keeps for another machine; None where it has not begun or it does not say (the default)."""
        return None

    @abstractmethod
    def run(self) -> dict[str, Any]:
        """Do the work (in a worker process); what it returns (JSON-able) goes into the record."""

    @abstractmethod
    def describe(self) -> str:
        """A few words for progress lines and the wall-time table."""

    @property
    def key(self) -> str:
        """Stable hash of (kind, settings, dependencies' keys)."""
        identity = {
            "kind": self.kind,
            "settings": self.settings(),
            "dependencies": [dep.key for dep in self.dependencies],
        }
        return hashlib.sha256(json.dumps(identity, sort_keys=True).encode()).hexdigest()[:16]


def record(job: Job, results: dict[str, Any] | None = None) -> dict[str, Any]:
    """The record the runner writes for ``job`` once it has finished with ``results``."""
    entry: dict[str, Any] = {"config": json.loads(json.dumps(job.settings()))}  # as it reads back: tuples are lists
    if job.dependencies:
        entry["dependencies"] = [dep.key for dep in job.dependencies]
    return {**entry, **(results or {})}


def write_record(job: Job, results: dict[str, Any] | None = None) -> None:
    """Mark ``job`` finished with ``results``: what the runner does after ``job.run()`` returned them (the ledger's
    copy first, so that a record in the run folder always has its copy). The record notes the versions it was made
    under (:func:`snapflow.reporting.machine.versions`)."""
    entry = {**record(job, results), "versions": versions()}
    if job.ledger_path is not None:
        write_json(job.ledger_path, entry)
    write_json(job.record_path, entry)


def read_record(job: Job) -> dict[str, Any]:
    """The finished job's record, from its run folder or else its ledger; FileNotFoundError if neither holds one
    made with the job's current settings."""
    for path in _record_paths(job):
        if holds_record_of(path, job):
            return json.loads(path.read_text())
    raise FileNotFoundError(f"no record of {job.describe()} made with its current settings at {job.record_path}")


def _record_paths(job: Job) -> tuple[Path, ...]:
    return (job.record_path,) if job.ledger_path is None else (job.record_path, job.ledger_path)


def holds_record_of(path: Path, job: Job) -> bool:
    """Whether ``path`` holds a record (finished or pending) of ``job`` with its current settings: the one test of
    whether something written belongs to the job."""
    try:
        stored = json.loads(path.read_text())
    except (FileNotFoundError, json.JSONDecodeError):
        return False
    expected = record(job)
    same_settings = stored.get("config") == expected["config"]
    return same_settings and stored.get("dependencies", []) == expected.get("dependencies", [])


def is_done(job: Job) -> bool:
    """The one cache rule: the record exists and was written for the job's current settings and dependencies."""
    return holds_record_of(job.record_path, job)


def is_recorded(job: Job) -> bool:
    """Whether the job's result is known: done here, or recorded in its ledger with its current settings."""
    return any(holds_record_of(path, job) for path in _record_paths(job))


def _pending_path(job: Job) -> Path:
    return job.record_path.with_name(f".{job.record_path.name}.pending")


def is_started(job: Job) -> bool:
    """Whether a run of the job with its current settings has begun here and not finished (it is running, or was
    interrupted: run again, it goes on from where it stopped)."""
    return holds_record_of(_pending_path(job), job) and not is_done(job)


def run_began(job: Job) -> float | None:
    """When the current run of a started ``job`` began (a time stamp), or None where it is not started: a job begun
    since the sweep that holds its folder began is running, not one an earlier run left interrupted."""
    try:
        return _pending_path(job).stat().st_mtime if is_started(job) else None
    except FileNotFoundError:  # finished between the two looks
        return None


def _remove(path: Path) -> None:
    if path.is_dir():
        shutil.rmtree(path)
    else:
        path.unlink(missing_ok=True)


def _start(job: Job) -> None:
    """Clear what a run with other settings (or an unknown one) left, bring back the progress a run on another
    machine kept, then note the settings this run has."""
    if not holds_record_of(_pending_path(job), job):
        for path in (*job.outputs, job.record_path):
            _remove(path)
        job.restore_progress()
        write_json(_pending_path(job), record(job))
    os.utime(_pending_path(job))  # when this run began (:func:`run_began`), a resumed one's too


def _restored(job: Job) -> bool:
    """Whether the outputs of ``job``, recorded in its ledger, came back from what it kept there; it is then done
    here."""
    if not job.restore_outputs():
        return False
    write_json(job.record_path, read_record(job))
    return True


def _finish(job: Job, results: dict[str, Any]) -> None:
    write_record(job, results)
    _pending_path(job).unlink(missing_ok=True)


def _copy_to_ledger(job: Job) -> None:
    """Give a job done here its ledger copy if it lacks one (it finished before its kind kept one)."""
    if job.ledger_path is not None and not holds_record_of(job.ledger_path, job):
        write_json(job.ledger_path, read_record(job))


def _awaited(jobs: Iterable[Job]) -> set[Job]:
    """The jobs that one of ``jobs`` depends on: the ones that unblock others, not results of their own."""
    return {dependency for job in jobs for dependency in job.dependencies}


def to_run(jobs: Iterable[Job]) -> list[Job]:
    """The jobs to run, shallowest first (collect before training before evaluation), and at one depth the ones no
    other job needs first (a teacher's evaluation before its students' training): each given job whose result is
    not known (:func:`is_recorded`), and the dependencies not done here of each job that runs, but those whose
    outputs come back from their ledger (:meth:`Job.restore_outputs`). A job done here whose ledger lacks its record
    gets it."""
    depth: dict[Job, int] = {}
    writers: dict[Path, Job] = {}

    def visit(job: Job, outputs_needed: bool) -> int:
        other = writers.setdefault(job.record_path, job)
        if other != job:
            raise InvalidInputError(
                f"{other.describe()} and {job.describe()} would write the same record {job.record_path}"
            )
        if is_done(job):
            _copy_to_ledger(job)
            return -1
        if is_recorded(job) and (not outputs_needed or _restored(job)):
            return -1
        if job not in depth:
            depth[job] = 1 + max((visit(dep, job.reads_outputs_of(dep)) for dep in job.dependencies), default=-1)
        return depth[job]

    for job in jobs:
        visit(job, False)
    awaited = _awaited(depth)
    # within a depth, the jobs nothing waits for (evaluations: results a session can commit, and the first word on
    # a teacher) before the ones that unblock others; a stable sort keeps the given order within each
    return sorted(depth, key=lambda job: (depth[job], job in awaited))


def run_jobs(
    jobs: Iterable[Job],
    workers: int = 1,
    progress: bool = True,
    description: str = "jobs",
    threads: int | None = None,
    backend: Backend | None = None,
    shared: Iterable[Path] = (),
) -> dict[str, float]:
    """Run the jobs of :func:`to_run` on ``backend`` (default: spawned processes on this machine), ``workers`` side by
    side, each on ``threads`` torch threads (default: the backend's cores / workers; fewer where other programs share
    the cores), a job once its dependencies have finished; returns each job's wall time (s) by description, in the
    order they finished. ``shared`` are the folders that every worker must see as this process does (the backend
    refuses to start where one would not).

    Of the jobs ready when a worker frees, one that no other job needs (an evaluation) goes first, whatever its
    depth, then :func:`to_run`'s order: a worker freed by a student evaluates it before starting a teacher of hours,
    so results a session can commit come as early as they can.

    A failed job stops the run with its own error once the jobs already running have finished, each of them recorded;
    a worker killed from outside (or for memory) stops it with a :class:`~snapflow.errors.SnapflowError` naming its
    job.
    """
    if workers < 1:
        raise InvalidInputError(f"workers must be at least 1, got {workers}")
    waiting = to_run(jobs)
    if not waiting:
        return {}
    unfinished = set(waiting)
    awaited = _awaited(waiting)
    times: dict[str, float] = {}
    running: dict[Future, Job] = {}
    bar = tqdm(total=len(waiting), desc=description, disable=not progress, dynamic_ncols=True)
    failure: BaseException | None = None  # the first job's error: no job starts after it, those running finish
    backend = backend or LocalBackend()
    with backend.session(workers, threads, shared) as threads_each:
        while (waiting and failure is None) or running:
            ready = sorted(
                (job for job in waiting if not unfinished.intersection(job.dependencies)),
                key=lambda job: job in awaited,
            )
            for job in ready[: workers - len(running)] if failure is None else ():
                waiting.remove(job)
                _start(job)
                running[backend.submit(job, threads_each)] = job
                bar.write(f"started: {job.describe()}")
            finished, _ = wait(running, return_when=FIRST_COMPLETED)
            for future in finished:
                job = running.pop(future)
                try:
                    results, seconds = future.result()
                except Exception as error:  # raised below, once the jobs running are recorded
                    failure = failure or _failure(job, error)
                    if running:
                        bar.write(f"failed: {job.describe()}; the {len(running)} job(s) running finish first")
                    continue
                _finish(job, results)  # a job that finished is recorded even when another one failed
                unfinished.discard(job)
                times[job.describe()] = seconds
                bar.write(f"done in {seconds / 60:.1f} min: {job.describe()}")
                bar.update()
    bar.close()
    if failure is not None:
        raise failure
    return times


def _failure(job: Job, error: Exception) -> Exception:
    """What stops the run for ``job``'s ``error``: its own error, or, where its worker died, one that says so."""
    if isinstance(error, WorkerDied):
        return SnapflowError(
            f"the worker running {job.describe()} died (killed, or out of memory); what finished is kept, and its "
            "checkpoints: run the same command again to go on"
        )
    return error


__all__ = [
    "JobProgress",
    "Job",
    "record",
    "write_record",
    "read_record",
    "is_done",
    "is_recorded",
    "is_started",
    "run_began",
    "to_run",
    "run_jobs",
]
