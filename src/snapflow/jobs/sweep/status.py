"""A sweep's state at a glance (``snapflow sweep CONFIG --status``): each job done here, kept (recorded in the
committed ledger: its result known, its outputs kept or not needed), running, or missing, and the machine time the
missing ones will take, estimated from the measured times of finished jobs of their kind."""

from __future__ import annotations

import json
from collections import defaultdict
from dataclasses import dataclass
from statistics import median

from snapflow.jobs.runner import Job, JobProgress, is_done, is_recorded, read_record, run_began
from snapflow.jobs.sweep.data_jobs import CollectJob
from snapflow.jobs.sweep.eval_jobs import EvalJob
from snapflow.jobs.sweep.planning import jobs
from snapflow.jobs.sweep.specs import SweepConfig
from snapflow.jobs.sweep.training_jobs import TrainJob
from snapflow.reporting.locks import held_since

STATES = ("done", "kept", "running", "missing")
# what a finished job's record says it took (s): a run's training, a collection, an evaluation's episodes
MEASURED_FIELDS = ("wall_time_s", "closed_loop_s")


@dataclass(frozen=True)
class JobStatus:
    """One job's state, and its measured time (finished) or the estimate of it (None: nothing of its kind measured)."""

    job: Job
    state: str
    seconds: float | None
    started: bool = False  # begun and not finished (running, or interrupted: it goes on from where it stopped)
    progress: JobProgress | None = None  # how far an unfinished one has come, here or kept elsewhere


def kind_of(job: Job) -> tuple[object, ...]:
    """The jobs whose times estimate each other's: a suite's collections (LIBERO-10's episodes are twice as long as
    Spatial's), a run's seeds, an evaluation's other seeds."""
    if isinstance(job, CollectJob):
        task = job.data.tasks[0]
        return ("collect", task.rpartition("_")[0] or task)
    if isinstance(job, TrainJob):
        return ("train", job.run_name)
    if isinstance(job, EvalJob):
        return ("eval", job.policy.run_name, job.mode.name, job.n_act, job.episodes_per_task, tuple(job.task_names))
    return (job.kind,)


def like_of(job: Job) -> tuple[object, ...] | None:
    """The jobs of other kinds whose times estimate a job's next best, or None: another policy's evaluation with as
    many network passes a chunk and actions a chunk on the same episodes (how often the policy runs, and how long)."""
    if isinstance(job, EvalJob):
        how = (job.evaluator, job.max_episode_steps, job.rtc)  # another evaluator, cut episodes, delays: other costs
        return ("eval-like", job.mode.num_steps, job.n_act, job.episodes_per_task, tuple(job.task_names), *how)
    return None


def _units(job: Job) -> int:
    """What a job's time grows with, where jobs of its type but of other kinds estimate it: an evaluation's episodes."""
    return len(job.task_names) * job.episodes_per_task if isinstance(job, EvalJob) else 1


def measured_seconds(job: Job) -> float | None:
    """What a finished job's record says it took, if it says."""
    try:
        entry = read_record(job)
    except (FileNotFoundError, json.JSONDecodeError):
        return None
    return next((float(entry[name]) for name in MEASURED_FIELDS if isinstance(entry.get(name), int | float)), None)


def sweep_status(config: SweepConfig) -> list[JobStatus]:
    """Every job the sweep's tables need, in planning order, with its state and its (measured or estimated) time."""
    sweep_began = held_since(config.output_dir)  # a job started since the sweep holding the folder began runs now
    planned = jobs(config)
    states, seconds, started = {}, {}, {}
    for job in planned:
        began = run_began(job)
        started[job] = began is not None
        finished = "done" if is_done(job) else "kept" if is_recorded(job) else None
        if finished:
            states[job] = finished
            seconds[job] = measured_seconds(job)
        else:
            running = sweep_began is not None and began is not None and began >= sweep_began
            states[job] = "running" if running else "missing"
    # each measured time counts for its kind, then for the jobs like it, and, where neither has one yet, for every job
    # of its type: per episode for evaluations (a row of one suite's 100 episodes against one of four suites' 400)
    by_kind: dict[tuple[object, ...], list[float]] = defaultdict(list)
    for job, value in seconds.items():
        if value is not None:
            by_kind[kind_of(job)].append(value)
            if (like := like_of(job)) is not None:
                by_kind[like].append(value)
            by_kind[kind_of(job)[:1]].append(value / _units(job))

    def estimate(job: Job) -> float | None:
        for key in (kind_of(job), like_of(job)):
            if key is not None and (measured := by_kind.get(key)):
                return median(measured)
        measured = by_kind.get(kind_of(job)[:1])
        return median(measured) * _units(job) if measured else None

    statuses = []
    for job in planned:
        progress = job.progress() if states[job] in ("running", "missing") else None
        left = seconds[job] if job in seconds else estimate(job)
        if progress is not None and left is not None:  # what is left of it
            left *= 1.0 - progress.share
        started_here = started[job] and states[job] in ("running", "missing")
        statuses.append(JobStatus(job, states[job], left, started_here, progress))
    return statuses


def format_status(config: SweepConfig, statuses: list[JobStatus], workers: int = 1) -> str:
    """The status as lines: a count of each state, one line a job, and the machine time left."""
    counts = {state: sum(status.state == state for status in statuses) for state in STATES}
    lines = [
        f"{config.name}: {len(statuses)} jobs: " + ", ".join(f"{count} {state}" for state, count in counts.items())
    ]
    for status in statuses:
        took = "" if status.seconds is None else f"{status.seconds / 60:.1f} min"
        if status.state in ("running", "missing"):
            took = f"~{took}" if took else "no job of its kind measured"
        note = ""
        if status.progress is not None:
            done = f"{status.progress.done} of {status.progress.total} {status.progress.unit}"
            note = f" ({done} done; goes on from there)" if status.state == "missing" else f" ({done} done)"
        elif status.started and status.state == "missing":
            note = " (started; goes on from where it stopped)"
        lines.append(f"  {status.state:8s} {status.job.describe().removeprefix(config.name + ': '):60s} {took}{note}")
    left = [status for status in statuses if status.state in ("running", "missing")]
    estimated = sum(status.seconds for status in left if status.seconds is not None)
    # counted job by job: two evaluations of one policy that differ only in their episodes read alike
    unmeasured = [status for status in left if status.seconds is None]
    hours = estimated / 3600
    summary = f"machine time left: ~{hours:.1f} h for {len(left) - len(unmeasured)} jobs"
    if workers > 1:
        summary += f" (~{hours / workers:.1f} h on {workers} workers)"
    if unmeasured:
        summary += f", and {len(unmeasured)} of kinds never measured here"
    return "\n".join([*lines, summary])


__all__ = ["STATES", "JobStatus", "kind_of", "measured_seconds", "sweep_status", "format_status"]
