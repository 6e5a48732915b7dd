"""Where the runner's jobs run: worker processes on this machine (the default), or tasks on a Ray cluster.

The runner (:func:`snapflow.jobs.runner.run_jobs`) decides which job starts when and writes every record; a backend
only starts one job's run somewhere and hands back a future of what it returned, so both backends run the same jobs
into the same files. A job's own error comes back as itself; a worker that ended before its job did comes back as
:class:`WorkerDied`. :func:`open_backend` is the one place that answers "local or Ray"; plain Python at import, so
that the CLI reads :data:`BACKENDS` without loading torch or Ray.
"""

from __future__ import annotations

import os
import time
from abc import ABC, abstractmethod
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import Future, ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from contextlib import contextmanager
from multiprocessing import get_context
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from snapflow.jobs.runner import Job

BACKENDS = ("local", "ray")  # snapflow sweep --backend: the first is the default
Outcome = tuple[dict[str, Any], float]  # what a job's run returned, and its wall time (s)


class WorkerDied(Exception):
    """The process running a job ended before the job did: killed from outside, out of memory, its machine lost."""


class Backend(ABC):
    """Runs one job at a time on request; :meth:`session` brackets a runner's use of it."""

    @abstractmethod
    def start(self, workers: int, threads: int | None) -> int:
        """Get ready to run ``workers`` jobs side by side; returns the torch threads each gets (``threads``, or the
        backend's share of its cores when None)."""

    @abstractmethod
    def submit(self, job: Job, threads: int) -> Future[Outcome]:
        """Start ``job``'s run on ``threads`` torch threads: a future of its outcome, whose exception is the job's own
        error or :class:`WorkerDied`."""

    @abstractmethod
    def stop(self) -> None:
        """Wait for the runs submitted, then release what :meth:`start` took (as much of it as it took)."""

    @abstractmethod
    def check_shared(self, folders: Iterable[Path]) -> None:
        """Refuse to start where a worker would not see ``folders`` (and the working folder) as this process does."""

    @contextmanager
    def session(self, workers: int, threads: int | None, shared: Iterable[Path] = ()) -> Iterator[int]:
        """Started for ``workers`` jobs side by side, ``shared`` checked, then stopped on leaving, whatever
        happened; yields the threads each job gets."""
        try:
            threads = self.start(workers, threads)
            self.check_shared(shared)
            yield threads
        finally:
            self.stop()


def work(job: Job, threads: int) -> Outcome:
    """A worker's entry point (a fresh process): run one job on ``threads`` torch threads; its results and wall
    time."""
    import torch  # here, in the worker: importing this module (the CLI does) loads no torch

    torch.set_num_threads(threads)
    started = time.perf_counter()
    results = job.run()
    return results, time.perf_counter() - started


def settled(source: Future[Outcome], error_of: Callable[[BaseException], BaseException]) -> Future[Outcome]:
    """A future settled as ``source`` is, its exception passed through ``error_of`` (a backend's own errors told as
    the job's, or as :class:`WorkerDied`)."""
    target: Future[Outcome] = Future()

    def settle(done: Future[Outcome]) -> None:
        error = done.exception()
        if error is None:
            target.set_result(done.result())
        else:
            target.set_exception(error_of(error))

    source.add_done_callback(settle)
    return target


class LocalBackend(Backend):
    """Spawned worker processes on this machine, one job a process.

    Spawn: each worker imports torch afresh, with its own thread count and no inherited locks; one job per process:
    the memory a job frees is not all handed back to the system (glibc keeps MuJoCo's), so a worker that went on to a
    second 500-episode evaluation reached 12.6 GB and was killed for memory.
    """

    def __init__(self) -> None:
        self._pool: ProcessPoolExecutor | None = None

    def start(self, workers: int, threads: int | None) -> int:
        self._pool = ProcessPoolExecutor(max_workers=workers, mp_context=get_context("spawn"), max_tasks_per_child=1)
        return threads or max(1, (os.cpu_count() or 1) // workers)

    def submit(self, job: Job, threads: int) -> Future[Outcome]:
        assert self._pool is not None, "start() first"
        return settled(self._pool.submit(work, job, threads), _local_error)

    def check_shared(self, folders: Iterable[Path]) -> None:
        """Nothing to check: every worker runs on this machine, in this process's working folder."""

    def stop(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=True)
            self._pool = None


def _local_error(error: BaseException) -> BaseException:
    return WorkerDied() if isinstance(error, BrokenProcessPool) else error


def open_backend(
    name: str = BACKENDS[0],
    address: str | None = None,
    gpus_per_job: float | None = None,
    memory_per_job: int | None = None,
) -> Backend:
    """The backend ``name`` of :data:`BACKENDS`; Ray's at ``address`` (None: Ray's own choice, ``RAY_ADDRESS`` or
    else a Ray started here), each training or evaluation job reserving ``gpus_per_job`` GPUs (None: one where the
    cluster has any) and every job ``memory_per_job`` bytes (None: none reserved). Ray is imported here: where it is
    not installed, a ModuleNotFoundError naming it (the CLI names its extra)."""
    if name == "local":
        return LocalBackend()
    if name == "ray":
        from snapflow.jobs.ray_backend import RayBackend

        return RayBackend(address, gpus_per_job, memory_per_job)
    raise ValueError(f"unknown backend {name!r}; known: {', '.join(BACKENDS)}")


__all__ = ["BACKENDS", "Backend", "LocalBackend", "WorkerDied", "open_backend", "settled", "work"]
