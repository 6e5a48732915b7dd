"""The runner's jobs as tasks on a Ray cluster (``snapflow sweep --backend ray``): the ``ray`` extra.

Each job is one Ray task that reserves what it needs: ``threads`` CPUs, a GPU (or ``gpus_per_job``) where it runs a
policy and the cluster has GPUs, and ``memory_per_job`` bytes where given. As on the local backend, a task runs in a
fresh worker process that ends with it and is never retried behind the runner's back. A task runs in the folder the
sweep was started from, so that the sweep's relative paths resolve there as they do here: the records it writes and
the paths they hold are the local runner's. That folder and the sweep's own must therefore be one shared file system
seen at the same path on every node, which :meth:`RayBackend.check_shared` checks before any job starts.
"""

from __future__ import annotations

import logging
import os
import secrets
import socket
from collections.abc import Iterable
from concurrent.futures import Future
from pathlib import Path
from typing import TYPE_CHECKING, Any

import ray
from ray.exceptions import NodeDiedError, ObjectLostError, OutOfMemoryError, RayTaskError, WorkerCrashedError
from ray.util.scheduling_strategies import NodeAffinitySchedulingStrategy

from snapflow.errors import InvalidInputError, SnapflowError
from snapflow.jobs.backends import Backend, Outcome, WorkerDied, settled, work

if TYPE_CHECKING:
    from snapflow.jobs.runner import Job

CHECK_TIMEOUT_S = 120  # for every node to answer the shared-folder check (a node starts a worker process for it)
CONNECT_TIMEOUT_S = 10  # for the head's port to answer: Ray itself waits many minutes on an address nobody serves


class RayBackend(Backend):
    """Jobs as Ray tasks on the cluster at ``address`` (None: ``RAY_ADDRESS``, else a Ray started on this machine);
    a ``HOST:PORT`` that nothing answers on is refused at once."""

    def __init__(
        self, address: str | None = None, gpus_per_job: float | None = None, memory_per_job: int | None = None
    ) -> None:
        _check_reachable(address)
        self.address = address
        self.gpus_per_job = gpus_per_job
        self.memory_per_job = memory_per_job
        self._gpus = 0.0
        self._nodes: list[dict[str, Any]] = []
        self._task: Any = None

    def start(self, workers: int, threads: int | None) -> int:
        ray.init(address=self.address, logging_level=logging.WARNING)
        # the nodes that can run a job (a head started with --num-cpus 0 runs none)
        self._nodes = [node for node in ray.nodes() if node["Alive"] and node["Resources"].get("CPU", 0) >= 1]
        if not self._nodes:
            raise SnapflowError(
                f"the Ray cluster at {self.address or 'RAY_ADDRESS'} has no node with a CPU to run jobs"
            )
        largest = {name: max(node["Resources"].get(name, 0) for node in self._nodes) for name in ("CPU", "GPU")}
        total_cpus, total_gpus = (
            sum(node["Resources"].get(name, 0) for node in self._nodes) for name in ("CPU", "GPU")
        )
        threads = threads or int(max(1, min(largest["CPU"], total_cpus // workers)))
        self._gpus = (1.0 if largest["GPU"] else 0.0) if self.gpus_per_job is None else self.gpus_per_job
        # a task that no node can hold waits forever: refuse it now, naming what to change
        _check_fits("--threads", threads, largest["CPU"], "CPUs")
        _check_fits("--gpus-per-job", self._gpus, largest["GPU"], "GPUs")
        if self.memory_per_job is not None:
            memory = max(node["Resources"].get("memory", 0) for node in self._nodes)
            _check_fits("--memory-per-job", self.memory_per_job / 2**30, memory / 2**30, "GiB of memory")
        self._task = ray.remote(max_calls=1, max_retries=0)(_work_in)
        print(
            f"Ray: {len(self._nodes)} node(s), {total_cpus:g} CPUs, {total_gpus:g} GPUs; each job reserves {threads} "
            f"CPU(s), a training or evaluation job {self._gpus:g} GPU(s)"
            + (f", every job {self.memory_per_job / 2**30:g} GiB" if self.memory_per_job is not None else "")
        )
        return threads

    def submit(self, job: Job, threads: int) -> Future[Outcome]:
        reserved: dict[str, Any] = {"num_cpus": threads, "num_gpus": self._gpus if job.uses_gpu else 0}
        if self.memory_per_job is not None:
            reserved["memory"] = self.memory_per_job
        run = self._task.options(**reserved).remote(os.getcwd(), job, threads)
        return settled(run.future(), _job_error)

    def stop(self) -> None:
        ray.shutdown()  # the tasks submitted have all finished: the runner waits for each

    def check_shared(self, folders: Iterable[Path]) -> None:
        """Refuse, in one line, a node that does not see the working folder and ``folders`` as this process does: a
        marker file written here must be there, at the same path, for a task pinned to each node."""
        places = dict.fromkeys(Path(folder).absolute() for folder in (Path.cwd(), *folders))
        token = secrets.token_hex(8)
        markers = [place / f".snapflow-shared-{token}" for place in places]
        try:
            for marker in markers:
                marker.parent.mkdir(parents=True, exist_ok=True)
                marker.write_text(token)
            probe = ray.remote(num_cpus=0, max_retries=0)(_unseen)
            answers = [
                probe.options(scheduling_strategy=NodeAffinitySchedulingStrategy(node["NodeID"], soft=False)).remote(
                    [str(marker) for marker in markers], token
                )
                for node in self._nodes
            ]
            unseen = ray.get(answers, timeout=CHECK_TIMEOUT_S)
        except ray.exceptions.GetTimeoutError:
            raise SnapflowError(
                f"the Ray nodes did not all answer the shared-folder check within {CHECK_TIMEOUT_S} s"
            ) from None
        finally:
            for marker in markers:
                marker.unlink(missing_ok=True)
        for node, missing in zip(self._nodes, unseen, strict=True):
            if missing:
                raise InvalidInputError(
                    f"the Ray node {node['NodeManagerAddress']} does not see {Path(missing[0]).parent} as this machine "
                    "does (a marker file written here is not there): every node must see the folder the sweep runs "
                    "from and the sweep's output_dir and results_dir at the same paths, on a shared file system"
                )


def _work_in(directory: str, job: Job, threads: int) -> Outcome:
    """A Ray task: run ``job`` from ``directory``, the folder the sweep started from, where its paths resolve."""
    os.chdir(directory)
    if not ray.get_gpu_ids():  # Ray leaves a task that reserved no GPU all of its node's: hide them (CUDA reads this
        os.environ["CUDA_VISIBLE_DEVICES"] = ""  # as it starts, at the job's first use of the GPU)
    return work(job, threads)


def _unseen(markers: list[str], token: str) -> list[str]:
    """A Ray task pinned to one node: the markers that are not there holding ``token``."""
    unseen = []
    for marker in markers:
        try:
            seen = Path(marker).read_text() == token
        except OSError:
            seen = False
        if not seen:
            unseen.append(marker)
    return unseen


def _job_error(error: BaseException) -> BaseException:
    """A job's own error as it was raised in its task (the task's traceback its cause), or :class:`WorkerDied` where
    the worker or its node went first."""
    if isinstance(error, RayTaskError) and isinstance(error.cause, Exception):
        error.cause.__cause__ = error
        return error.cause
    if isinstance(error, (WorkerCrashedError, NodeDiedError, OutOfMemoryError, ObjectLostError)):
        return WorkerDied()
    return error


def _check_reachable(address: str | None) -> None:
    """Refuse at once a ``host:port`` that nothing answers on (Ray itself would wait for minutes)."""
    host, _, port = (address or "").rpartition(":")
    if not host or "://" in address or not port.isdigit():
        return  # Ray's own forms ("auto", ray://...) and no address: Ray's to resolve
    try:
        socket.create_connection((host, int(port)), timeout=CONNECT_TIMEOUT_S).close()
    except OSError as error:
        raise SnapflowError(
            f"no Ray cluster answers at --address {address} ({error.strerror or error}): start its head with "
            "`ray start --head` or give its address"
        ) from None


def _check_fits(flag: str, wanted: float, largest: float, what: str) -> None:
    if wanted > largest:
        raise InvalidInputError(f"{flag} {wanted:g} is more than any Ray node has ({largest:g} {what})")


__all__ = ["RayBackend"]
