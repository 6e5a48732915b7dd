"""A sweep's work as typed jobs for :mod:`snapflow.jobs.runner`: collect each task -> put the tasks together -> train
teachers -> distill students -> evaluate, each keyed by its full resolved settings and those of the jobs it reads.

Collection is one job a task so that a long one (LIBERO with cameras: ~15 s an episode) runs on several workers and
an interrupted sweep keeps the tasks it finished."""

from __future__ import annotations

import shutil
import time
from contextlib import ExitStack
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, ClassVar

from snapflow.adapters.lerobot_config import SMOLVLM_SIZES
from snapflow.data.collect import collect
from snapflow.data.demonstrations import Demonstrations
from snapflow.envs.factory import make_benchmark
from snapflow.evaluation.config import OFFLINE_SAMPLES
from snapflow.evaluation.pipeline import evaluate
from snapflow.flow.modes import SamplingMode
from snapflow.jobs.runner import Job, holds_record_of, record, run_jobs, to_run
from snapflow.jobs.sweep.schema import EVALUATORS, TRAINERS, DataSpec, LeRobotSpec, RowSpec, SweepConfig, TableSpec
from snapflow.policies.checkpoint import resolve_checkpoint
from snapflow.policies.configuration import PolicyConfig
from snapflow.policies.factory import policy_type_of
from snapflow.reporting.files import write_json
from snapflow.reporting.locks import hold_run_lock
from snapflow.reporting.records import as_record
from snapflow.sources import LEROBOT_EXPORT_DIRECTORY, open_policy
from snapflow.training.checkpoint import copy_checkpoint, install_checkpoint, keep_checkpoint, read_kept
from snapflow.training.config import VAL_FRACTION, TrainConfig
from snapflow.training.recipes import DistillSettings
from snapflow.training.stages import distill, train_teacher

RECORD = "job.json"  # a collect or train job's record, inside the folder it fills
LEROBOT_REPO_ID = "local/lerobot"  # the LeRobotDataset's name: it is read from its folder, never from a hub
LEROBOT_TRAIN_DIRECTORY = "lerobot-train"  # a lerobot-train student's run, inside its run folder
KEPT_JOB = "job.json"  # beside a lerobot-eval row's kept tasks: the record of the job they belong to


class FolderJob(Job):
    """A job that fills one folder, ``directory``, and keeps its record there."""

    directory: Path

    @property
    def record_path(self) -> Path:
        return self.directory / RECORD

    @property
    def outputs(self) -> tuple[Path, ...]:
        return (self.directory,)


@dataclass(frozen=True)
class CollectJob(FolderJob):
    """The expert demonstrations of one task (``data.tasks`` holds it alone), in ``directory``."""

    kind: ClassVar[str] = "collect"
    sweep: str
    directory: Path
    data: DataSpec

    def settings(self) -> dict[str, Any]:
        return as_record(self.data)

    def run(self) -> dict[str, Any]:
        data = self.data
        collect(
            make_benchmark(data.env),
            list(data.tasks),
            data.episodes_per_task,
            self.directory,
            data.image_size,
            progress=False,
            extra_cameras=data.extra_cameras,
            action_noise=data.action_noise,
        )
        return {}

    def describe(self) -> str:
        return f"{self.sweep}: collect {self.data.tasks[0]}"


@dataclass(frozen=True)
class DataJob(FolderJob):
    """The sweep's demonstrations: every task's collected part, in task order, in one folder."""

    kind: ClassVar[str] = "data"
    sweep: str
    directory: Path
    data: DataSpec
    parts: tuple[CollectJob, ...]

    def settings(self) -> dict[str, Any]:
        return as_record(self.data)

    @property
    def dependencies(self) -> tuple[Job, ...]:
        return self.parts

    def run(self) -> dict[str, Any]:
        Demonstrations.concatenate([Demonstrations.load(part.directory) for part in self.parts]).save(self.directory)
        return {}

    def describe(self) -> str:
        return f"{self.sweep}: demonstrations of {len(self.parts)} tasks"


@dataclass(frozen=True)
class LeRobotDatasetJob(FolderJob):
    """The sweep's demonstrations written as a LeRobotDataset (LeRobot's own writer), which its LeRobot runs read."""

    kind: ClassVar[str] = "lerobot-dataset"
    sweep: str
    directory: Path
    data: DataJob

    def settings(self) -> dict[str, Any]:
        return {"repo_id": LEROBOT_REPO_ID}

    @property
    def dependencies(self) -> tuple[Job, ...]:
        return (self.data,)

    def run(self) -> dict[str, Any]:
        from snapflow.adapters.lerobot.dataset import write_lerobot_dataset

        shutil.rmtree(self.directory, ignore_errors=True)  # an interrupted write: LeRobot's writer wants a new folder
        benchmark = make_benchmark(self.data.data.env)
        demonstrations = Demonstrations.load(self.data.directory)
        write_lerobot_dataset(
            demonstrations, self.directory, LEROBOT_REPO_ID, benchmark.fps, benchmark.camera, progress=False
        )
        return {}

    def describe(self) -> str:
        return f"{self.sweep}: demonstrations as a LeRobotDataset"


@dataclass(frozen=True)
class TrainJob(FolderJob):
    """A teacher (``policy``: flow matching on the data) or a student (``teacher`` and ``distill``), in ``directory``.

    Both resume an interrupted run of the same settings; the runner clears the folder of one made with others.
    """

    kind: ClassVar[str] = "train"
    sweep: str
    run_name: str
    directory: Path
    data: DataJob
    train: TrainConfig  # its seed is the run's
    policy: PolicyConfig | None = None
    teacher: TrainJob | None = None
    distill: DistillSettings | None = None
    ledger: Path | None = None
    kept: Path | None = None  # where its checkpoint is kept to be committed (its run's ``commit_checkpoint``)
    lerobot: LeRobotSpec | None = None  # a LeRobot teacher's settings
    trainer: str = TRAINERS[0]  # a LeRobot student's trainer
    dataset: LeRobotDatasetJob | None = None  # what a LeRobot run (teacher or student) trains on

    @property
    def seed(self) -> int:
        return self.train.seed

    @property
    def policy_path(self) -> Path:
        """Where the trained policy is, as :func:`snapflow.sources.open_policy` opens it: the run folder of a
        built-in policy, the LeRobot policy folder a LeRobot run exports, or ``lerobot-train``'s last checkpoint."""
        if self.dataset is None:
            return self.directory
        if self.trainer == "lerobot-train":
            from snapflow.training.lerobot_student import LAST_CHECKPOINT

            return self.directory / LEROBOT_TRAIN_DIRECTORY / LAST_CHECKPOINT
        return self.directory / LEROBOT_EXPORT_DIRECTORY

    @property
    def ledger_path(self) -> Path | None:
        return self.ledger

    def settings(self) -> dict[str, Any]:
        if self.lerobot is not None:
            return {"lerobot": as_record(self.lerobot), "train": as_record(self.train), "val_fraction": VAL_FRACTION}
        if self.teacher is None:
            policy = {"type": policy_type_of(self.policy).name, **self.policy.to_dict()}
            return {"policy": policy, "train": as_record(self.train), "val_fraction": VAL_FRACTION}
        # held-out episodes: the teacher's; the trainer only where it is not snapflow's (the records made before)
        trainer = {"trainer": self.trainer} if self.trainer != TRAINERS[0] else {}
        return {"distill": as_record(self.distill), "train": as_record(self.train), **trainer}

    @property
    def dependencies(self) -> tuple[Job, ...]:
        needs = (self.data,) if self.dataset is None else (self.data, self.dataset)
        return needs if self.teacher is None else (*needs, self.teacher)

    def run(self) -> dict[str, Any]:
        if self.dataset is not None:
            return self._run_lerobot()
        keep = self._keep_progress if self.kept is not None else None
        if self.teacher is None:
            state = train_teacher(
                self.data.directory,
                self.directory,
                self.policy,
                self.train,
                VAL_FRACTION,
                resume=True,
                progress=False,
                on_checkpoint=keep,
            )
        else:
            state = distill(
                self.teacher.directory,
                self.data.directory,
                self.directory,
                self.train,
                self.distill,
                resume=True,
                progress=False,
                on_checkpoint=keep,
            )
        if self.kept is not None:
            self._keep(resolve_checkpoint(self.directory), finished=True)
        return {"step": state["step"], "wall_time_s": state["wall_time_s"]}  # the tables' training cost

    def _run_lerobot(self) -> dict[str, Any]:
        """A LeRobot teacher from scratch, or its student by snapflow's trainer or by ``lerobot-train``. The kept
        checkpoint (``commit_checkpoint``) is the trainer's own ``keep_progress``: a fresh machine resumes from it."""
        from snapflow.training.lerobot import distill_lerobot, train_smolvla_teacher

        assert self.dataset is not None
        dataset = self.dataset.directory
        if self.trainer == "lerobot-train":
            return self._run_lerobot_train()
        if self.lerobot is not None:
            spec = self.lerobot
            size = SMOLVLM_SIZES[spec.smolvlm]
            if spec.image_size is not None:
                size = replace(size, image_size=spec.image_size)
            state = train_smolvla_teacher(
                dataset,
                LEROBOT_REPO_ID,
                self.directory,
                self.train,
                size,
                spec.chunk_size,
                spec.n_action_steps,
                VAL_FRACTION,
                resume=True,
                progress=False,
                keep_progress=self.kept,
            )
        else:
            assert self.teacher is not None
            state = distill_lerobot(
                str(self.teacher.policy_path),
                dataset,
                LEROBOT_REPO_ID,
                self.directory,
                self.train,
                self.distill,
                resume=True,
                progress=False,
                keep_progress=self.kept,
            )
        if self.kept is not None:
            self.keep_lerobot_policy()
        return {"step": state["step"], "wall_time_s": state["wall_time_s"]}

    def _run_lerobot_train(self) -> dict[str, Any]:
        """The teacher written as its student type, then ``lerobot-train`` on the training episodes (the teacher's
        held-out ones stay out)."""
        import torch

        from snapflow.training.lerobot_student import run_lerobot_train, write_student

        assert self.teacher is not None and self.dataset is not None
        began = time.perf_counter()
        teacher = str(self.teacher.policy_path)
        student = self.directory / "student"
        if not (student / "config.json").is_file():
            shutil.rmtree(student, ignore_errors=True)
            write_student(teacher, student, self.distill)
        # the dataset's episodes are the demonstrations' in their order: the teacher's split holds the same ones out
        training_episodes, _ = Demonstrations.load(self.data.directory).split(VAL_FRACTION)
        run_lerobot_train(
            student,
            self.dataset.directory,
            LEROBOT_REPO_ID,
            self.directory / LEROBOT_TRAIN_DIRECTORY,
            self.train,
            training_episodes,
            "cuda" if torch.cuda.is_available() else "cpu",
            torch.get_num_threads(),
        )
        if self.kept is not None:
            self.keep_lerobot_policy()
        return {"step": self.train.steps, "wall_time_s": time.perf_counter() - began}

    def keep_lerobot_policy(self) -> None:
        """Keep a finished LeRobot run's policy folder (a teacher's or student's export, or ``lerobot-train``'s last
        checkpoint) in :attr:`kept`, its processors and its local VLM inside, which :meth:`restore_outputs` puts back
        on another machine and ``open_policy`` opens anywhere; the policy alone: an unfinished run resumes from its
        trainer's checkpoints."""
        from snapflow.adapters.lerobot.local_vlm import bundle_vlm

        assert self.kept is not None
        keep_checkpoint(self.policy_path, self.kept, {"job": record(self), "finished": True}, prepare=bundle_vlm)

    def _keep_progress(self, checkpoint: Path) -> None:
        self._keep(checkpoint, finished=False)

    def _keep(self, checkpoint: Path, finished: bool) -> None:
        """Make ``checkpoint`` the one kept in :attr:`kept`: all that resuming reads while the run goes on, the policy
        alone (what students and evaluations read) once it has finished."""
        assert self.kept is not None
        keep_checkpoint(checkpoint, self.kept, {"job": record(self), "finished": finished}, policy_only=finished)

    def _kept_checkpoint(self, finished: bool) -> Path | None:
        """The checkpoint kept by a run with the current settings that had (or had not) ``finished``, if any."""
        kept = read_kept(self.kept) if self.kept is not None else None
        if kept is None or kept[1] != {"job": record(self), "finished": finished}:
            return None
        return kept[0]

    def _install(self, checkpoint: Path) -> None:
        """Put a kept checkpoint into the run folder as its latest."""
        install_checkpoint(checkpoint, self.directory, self.train.keep_checkpoints)

    def restore_outputs(self) -> bool:
        checkpoint = self._kept_checkpoint(finished=True)
        if checkpoint is None:
            return False
        shutil.rmtree(self.directory, ignore_errors=True)
        if self.dataset is not None:  # a LeRobot policy folder, where its trainer leaves it
            copy_checkpoint(checkpoint, self.policy_path)
        else:
            self._install(checkpoint)
        return True

    def restore_progress(self) -> bool:
        checkpoint = self._kept_checkpoint(finished=False)
        if checkpoint is None:
            return False
        self._install(checkpoint)
        return True

    def describe(self) -> str:
        return f"{self.sweep}: train {self.run_name} seed {self.seed}"


@dataclass(frozen=True)
class EvalJob(Job):
    """One (policy, sampling mode, actions per chunk, episodes per task): closed-loop success and offline metrics on
    the held-out demonstrations; its record, at ``path``, holds the evaluation row."""

    kind: ClassVar[str] = "eval"
    policy: TrainJob
    mode: SamplingMode
    n_act: int
    episodes_per_task: int
    path: Path
    ledger: Path | None = None
    first_variation: int = 0  # each task's episodes from this evaluation variation on
    evaluator: str = EVALUATORS[0]  # snapflow's evaluator, or LeRobot's lerobot-eval (no offline metrics)

    @property
    def by_lerobot_eval(self) -> bool:
        """Whether LeRobot's ``lerobot-eval`` runs its episodes rather than snapflow's evaluator."""
        return self.evaluator != EVALUATORS[0]

    def settings(self) -> dict[str, Any]:
        return {
            "mode": as_record(self.mode),
            "n_act": self.n_act,
            "episodes_per_task": self.episodes_per_task,
            "seed": self.policy.seed,
            **({} if self.by_lerobot_eval else {"offline_samples": OFFLINE_SAMPLES}),
            # only where set: the records made before they could be chosen are of the first variations, by snapflow's
            **({"first_variation": self.first_variation} if self.first_variation else {}),
            **({"evaluator": self.evaluator} if self.by_lerobot_eval else {}),
        }

    @property
    def dependencies(self) -> tuple[Job, ...]:
        return (self.policy, self.policy.data)

    @property
    def record_path(self) -> Path:
        return self.path

    @property
    def ledger_path(self) -> Path | None:
        return self.ledger

    @property
    def episodes_dir(self) -> Path:
        """Where its episodes are logged as they finish (by lerobot-eval: each task's run): an interrupted evaluation
        goes on from them."""
        return self.path.with_name(f"{self.path.stem}.episodes")

    @property
    def outputs(self) -> tuple[Path, ...]:
        return (self.episodes_dir,)

    def run(self) -> dict[str, Any]:
        if self.by_lerobot_eval:
            return self._run_lerobot_eval()
        collected = self.policy.data
        loaded = open_policy(str(self.policy.policy_path))
        # the runner clears the log of a run with other settings, so what is left is this evaluation's to resume
        report = evaluate(
            [(self.mode.name, loaded, self.mode)],
            make_benchmark(collected.data.env),
            list(collected.data.tasks),
            self.episodes_per_task,
            self.n_act,
            collected.directory,
            seed=self.policy.seed,
            progress=False,
            timing=False,
            episode_logs=self.episodes_dir,
            resume=True,
            first_variation=self.first_variation,
            # lerobot-train records no held-out share: it trained on its teacher's split, every run's here
            val_fraction=VAL_FRACTION if self.policy.trainer == "lerobot-train" else None,
        )
        return report.rows[self.mode.name].to_dict()

    def reads_outputs_of(self, dependency: Job) -> bool:
        """lerobot-eval reads the policy alone: the demonstrations (offline metrics) are snapflow's evaluator's."""
        return not self.by_lerobot_eval or dependency != self.policy.data

    @property
    def kept_tasks(self) -> Path | None:
        """By lerobot-eval, beside the ledger's record: each finished task's ``eval_info.json`` and wall time, and the
        job they belong to (``job.json``), so that another machine goes on from the next task."""
        if self.ledger is None or not self.by_lerobot_eval:
            return None
        return self.ledger.with_suffix("")

    def _kept_by_this_job(self) -> bool:
        kept = self.kept_tasks
        return kept is not None and holds_record_of(kept / KEPT_JOB, self)

    def restore_progress(self) -> bool:
        from snapflow.evaluation.lerobot_eval import restore_kept_tasks

        if not self._kept_by_this_job():
            return False
        return bool(restore_kept_tasks(self.kept_tasks, self.episodes_dir))

    def _run_lerobot_eval(self) -> dict[str, Any]:
        """LeRobot's ``lerobot-eval`` on each task, its ``eval_info.json`` files kept beside the ledger's record."""
        import torch

        from snapflow.evaluation.lerobot_eval import run_lerobot_eval

        data = self.policy.data.data
        kept = self.kept_tasks
        if kept is not None and not self._kept_by_this_job():  # tasks another job's settings kept are not this one's
            shutil.rmtree(kept, ignore_errors=True)
            write_json(kept / KEPT_JOB, record(self))
        row = run_lerobot_eval(
            self.policy.policy_path,
            list(data.tasks),
            self.episodes_per_task,
            data.image_size,
            self.n_act,
            self.mode,
            self.episodes_dir,
            threads=torch.get_num_threads(),
            kept=kept,
        )
        return row.to_dict()

    def describe(self) -> str:
        policy = self.policy
        by = f", by {self.evaluator}" if self.by_lerobot_eval else ""
        return (
            f"{policy.sweep}: evaluate {policy.run_name} seed {policy.seed} ({self.mode.name}; n_act {self.n_act}{by})"
        )


def data_job(config: SweepConfig) -> DataJob:
    """The sweep's demonstrations, from one collection job a task."""
    parts = tuple(
        CollectJob(config.name, config.collect_dir(task), replace(config.data, tasks=(task,)))
        for task in config.data.tasks
    )
    return DataJob(config.name, config.data_dir, config.data, parts)


def train_job(config: SweepConfig, run: str, seed: int) -> TrainJob:
    """Run ``run`` of the sweep on ``seed``, a student with its teacher's job of the same seed; a LeRobot run (a
    LeRobot teacher or its student) reads the demonstrations as a LeRobotDataset."""
    spec = config.runs[run]
    teacher = train_job(config, spec.teacher, seed) if spec.teacher is not None else None
    train = replace(spec.train, seed=seed)
    directory = config.run_dir(run, seed)
    ledger = config.ledger_path(directory / RECORD)
    kept = ledger.parent / "checkpoint" if spec.commit_checkpoint else None
    data = data_job(config)
    lerobot = spec.lerobot is not None or (teacher is not None and teacher.dataset is not None)
    dataset = LeRobotDatasetJob(config.name, config.lerobot_dataset_dir, data) if lerobot else None
    return TrainJob(
        config.name,
        run,
        directory,
        data,
        train,
        spec.policy,
        teacher,
        spec.distill,
        ledger,
        kept,
        spec.lerobot,
        spec.trainer,
        dataset,
    )


def eval_job(config: SweepConfig, table: TableSpec, row: RowSpec, seed: int) -> EvalJob:
    """The evaluation behind one cell (row, seed) of a table of ``config``: the row's own sweep's, where it reads
    another's."""
    owner = row.owner(config)
    first, evaluator = table.first_variation, table.evaluator
    path = owner.eval_path(row.run, seed, row.mode, row.n_act, table.episodes_per_task, first, evaluator)
    policy = train_job(owner, row.run, seed)
    ledger = owner.ledger_path(path)
    return EvalJob(policy, row.mode, row.n_act, table.episodes_per_task, path, ledger, first, evaluator)


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
    configs: list[SweepConfig], workers: int = 1, progress: bool = True, threads: int | None = None
) -> dict[str, float]:
    """Run every job of the sweeps that is not done on ``workers`` processes (each on ``threads`` torch threads,
    by default cores / workers), a ready evaluation first, then earlier
    pipeline stages first across the sweeps (their jobs are the longest and unblock the others); returns each job's
    wall time (s).

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
        return run_jobs(
            [job for config in configs for job in plan(config)], workers, progress, description="sweep", threads=threads
        )


__all__ = [
    "RECORD",
    "CollectJob",
    "DataJob",
    "LeRobotDatasetJob",
    "TrainJob",
    "EvalJob",
    "data_job",
    "train_job",
    "eval_job",
    "jobs",
    "plan",
    "run_sweeps",
]
