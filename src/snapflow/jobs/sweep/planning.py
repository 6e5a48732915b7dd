"""A sweep's work as typed jobs for :mod:`snapflow.jobs.runner`: collect each task -> put the tasks together -> train
teachers -> distill students -> evaluate, each keyed by its full resolved settings and those of the jobs it reads.

Collection is one job a task so that a long one (LIBERO with cameras: ~15 s an episode) runs on several workers and
an interrupted sweep keeps the tasks it finished."""

from __future__ import annotations

from contextlib import ExitStack
from dataclasses import replace

from snapflow.families import family_of
from snapflow.jobs.backends import Backend
from snapflow.jobs.runner import Job, run_jobs, to_run
from snapflow.jobs.sweep.data_jobs import RECORD, CollectJob, DataJob, LeRobotDatasetJob
from snapflow.jobs.sweep.eval_jobs import EvalJob
from snapflow.jobs.sweep.specs import RowSpec, SweepConfig, TableSpec
from snapflow.jobs.sweep.training_jobs import TrainJob
from snapflow.reporting.locks import hold_run_lock


def data_job(config: SweepConfig) -> DataJob:
    """The sweep's demonstrations, from one collection job a task; a video collection's record and its collection are
    kept beside the sweep's records (to be committed)."""
    parts = []
    for task in config.data.tasks:
        directory = config.collect_dir(task)
        ledger = config.ledger_path(directory / RECORD) if config.data.video is not None else None
        parts.append(CollectJob(config.name, directory, replace(config.data, tasks=(task,)), ledger))
    return DataJob(config.name, config.data_dir, config.data, tuple(parts))


def train_job(config: SweepConfig, run: str, seed: int) -> TrainJob:
    """Run ``run`` of the sweep on ``seed``, a student with its teacher's job of the same seed; a run of a family that
    reads a LeRobotDataset (a LeRobot teacher or its student) reads the demonstrations written as one."""
    spec = config.runs[run]
    teacher = train_job(config, spec.teacher, seed) if spec.teacher is not None else None
    train = replace(spec.train, seed=seed)
    directory = config.run_dir(run, seed)
    ledger = config.ledger_path(directory / RECORD)
    kept = ledger.parent / "checkpoint" if spec.commit_checkpoint else None
    data = data_job(config)
    family = teacher.family if teacher is not None else family_of(spec.spec)
    dataset = LeRobotDatasetJob(config.name, config.lerobot_dataset_dir, data) if family.reads_dataset else None
    return TrainJob(
        config.name,
        run,
        directory,
        data,
        train,
        spec.spec,
        teacher,
        spec.distill,
        ledger,
        kept,
        spec.trainer,
        dataset,
    )


def eval_job(config: SweepConfig, table: TableSpec, row: RowSpec, seed: int) -> EvalJob:
    """The evaluation behind one cell (row, seed) of a table of ``config``: the row's own sweep's, where it reads
    another's."""
    owner = row.owner(config)
    first, evaluator, tasks, cut = table.first_variation, table.evaluator, table.tasks, table.max_episode_steps
    episodes = table.episodes_per_task
    path = owner.eval_path(row.run, seed, row.mode, row.n_act, episodes, first, evaluator, tasks, cut, row.rtc)
    policy = train_job(owner, row.run, seed)
    ledger = owner.ledger_path(path)
    return EvalJob(policy, row.mode, row.n_act, episodes, path, ledger, first, evaluator, tasks, cut, row.rtc)


def jobs(config: SweepConfig) -> list[Job]:
    """Every job the sweep's tables need, done or not: collect, the runs (each teacher before its students), evals.
    A row that reads another sweep is that sweep's to run (under its own lock), so none of its jobs is here."""
    data = data_job(config)
    evals = [
        eval_job(config, table, row, seed)
        for table in config.tables
        for row in table.rows
        if row.sweep is None
        for seed in table.seeds
    ]
    trains = [train for job in evals for train in (job.policy.teacher, job.policy) if train is not None]
    datasets = [train.dataset for train in trains if train.dataset is not None]
    return list(dict.fromkeys([*data.parts, data, *datasets, *trains, *evals]))


def plan(config: SweepConfig) -> list[Job]:
    """The sweep's jobs that will run, dependencies first: each evaluation and run the tables read whose record is
    missing (here and in the committed ledger) or was made with other settings, and each job that one of those needs
    and that is not done here (:func:`snapflow.jobs.runner.to_run`)."""
    return to_run(job for job in jobs(config) if isinstance(job, (TrainJob, EvalJob)))


def run_sweeps(
    configs: list[SweepConfig],
    workers: int = 1,
    progress: bool = True,
    threads: int | None = None,
    backend: Backend | None = None,
) -> dict[str, float]:
    """Run every job of the sweeps that is not done on ``backend`` (default: processes on this machine), ``workers``
    side by side (each on ``threads`` torch threads, by default the backend's cores / workers), a ready evaluation
    first, then earlier pipeline stages first across the sweeps (their jobs are the longest and unblock the others);
    returns each job's wall time (s). Every worker must see each sweep's output_dir and results_dir (its ledger) as
    this process does: the backend checks it before any job starts.

    Each sweep's output_dir is held from planning to the last job: a second sweep over the same folder is refused at
    once with :class:`~snapflow.reporting.locks.RunLockedError` (the workers hold their jobs' own folders).
    """
    with ExitStack() as held:
        for config in configs:
            held.enter_context(
                hold_run_lock(
                    config.output_dir, "snapflow sweep", "wait for it to finish or give the sweep another output_dir"
                )
            )
        planned = [job for config in configs for job in plan(config)]
        shared = [folder for config in configs for folder in (config.output_dir, config.results_dir)]
        return run_jobs(planned, workers, progress, "sweep", threads, backend, shared)


__all__ = ["data_job", "train_job", "eval_job", "jobs", "plan", "run_sweeps"]
