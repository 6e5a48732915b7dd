"""A sweep's run as a job: a teacher trained, or a student distilled from one, built-in or LeRobot."""

from __future__ import annotations

import shutil
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, ClassVar

from snapflow.adapters.lerobot_config import SMOLVLM_SIZES
from snapflow.data.demonstrations import Demonstrations
from snapflow.jobs.runner import Job, record
from snapflow.jobs.sweep.data_jobs import LEROBOT_REPO_ID, DataJob, FolderJob, LeRobotDatasetJob
from snapflow.jobs.sweep.specs import TRAINERS, LeRobotSpec
from snapflow.policies.checkpoint import resolve_checkpoint
from snapflow.policies.configuration import PolicyConfig
from snapflow.policies.factory import policy_type_of
from snapflow.reporting.records import as_record
from snapflow.sources import LEROBOT_EXPORT_DIRECTORY
from snapflow.training.checkpoint import copy_checkpoint, install_checkpoint, keep_checkpoint, read_kept
from snapflow.training.config import VAL_FRACTION, TrainConfig
from snapflow.training.recipes import DistillSettings
from snapflow.training.stages import distill, train_teacher

LEROBOT_TRAIN_DIRECTORY = "lerobot-train"  # a lerobot-train student's run, inside its run folder


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
        from snapflow.training.lerobot import distill_lerobot, train_lerobot_teacher

        assert self.dataset is not None
        dataset = self.dataset.directory
        if self.trainer == "lerobot-train":
            return self._run_lerobot_train()
        if self.lerobot is not None:
            spec = self.lerobot
            size = SMOLVLM_SIZES[spec.smolvlm]
            if spec.image_size is not None:
                size = replace(size, image_size=spec.image_size)
            state = train_lerobot_teacher(
                spec.policy_type,
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


__all__ = ["LEROBOT_TRAIN_DIRECTORY", "TrainJob"]
