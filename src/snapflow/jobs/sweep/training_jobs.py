"""A sweep's run as a job: a teacher trained, or a student distilled from one, by its policy's family."""

from __future__ import annotations

import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

from snapflow.adapters.lerobot_config import LeRobotSpec
from snapflow.families import PolicyFamily, Progress, Source, StudentRun, TeacherRun, family_of
from snapflow.jobs.runner import Job, JobProgress, is_started, record
from snapflow.jobs.sweep.data_jobs import LEROBOT_REPO_ID, DataJob, FolderJob, LeRobotDatasetJob
from snapflow.jobs.sweep.specs import TRAINERS
from snapflow.policies.configuration import PolicyConfig
from snapflow.reporting.records import as_record
from snapflow.training.checkpoint import STEP_PREFIX, install_checkpoint, keep_checkpoint, read_kept
from snapflow.training.config import VAL_FRACTION, TrainConfig
from snapflow.training.recipes import DistillSettings


@dataclass(frozen=True)
class TrainJob(FolderJob):
    """A teacher (``spec``: flow matching on the data) or a student (``teacher`` and ``distill``), in ``directory``.

    Both resume an interrupted run of the same settings; the runner clears the folder of one made with others.
    """

    kind: ClassVar[str] = "train"
    uses_gpu: ClassVar[bool] = True
    sweep: str
    run_name: str
    directory: Path
    data: DataJob
    train: TrainConfig  # its seed is the run's
    spec: PolicyConfig | LeRobotSpec | None = None  # a teacher's policy, as its family describes it
    teacher: TrainJob | None = None
    distill: DistillSettings | None = None
    ledger: Path | None = None
    kept: Path | None = None  # where its checkpoint is kept to be committed (its run's ``commit_checkpoint``)
    trainer: str = TRAINERS[0]  # a student's: one of its family's trainers
    dataset: LeRobotDatasetJob | None = None  # what a run of a family that reads a LeRobotDataset trains on

    @property
    def seed(self) -> int:
        return self.train.seed

    @property
    def family(self) -> PolicyFamily:
        """The family of its policy: a teacher's own, a student's its teacher's."""
        return family_of(self.spec) if self.teacher is None else self.teacher.family

    @property
    def policy_path(self) -> Path:
        """Where the trained policy is, as :func:`snapflow.sources.open_policy` opens it (its family says)."""
        return self.family.policy_path(self.directory, self.trainer)

    @property
    def ledger_path(self) -> Path | None:
        return self.ledger

    def settings(self) -> dict[str, Any]:
        if self.teacher is None:
            spec = self.family.teacher_record(self.spec)
            return {**spec, "train": as_record(self.train), "val_fraction": VAL_FRACTION}
        # held-out episodes: the teacher's; the trainer only where it is not snapflow's (the records made before)
        trainer = {"trainer": self.trainer} if self.trainer != TRAINERS[0] else {}
        return {"distill": as_record(self.distill), "train": as_record(self.train), **trainer}

    @property
    def dependencies(self) -> tuple[Job, ...]:
        needs = (self.data,) if self.dataset is None else (self.data, self.dataset)
        return needs if self.teacher is None else (*needs, self.teacher)

    def run(self) -> dict[str, Any]:
        """Train or distil by the family's own route, on the demonstrations and (a LeRobot run) their LeRobotDataset;
        a kept run keeps its progress as it goes (a built-in run each checkpoint with its record, a LeRobot run its
        trainer's own) and its policy once it has finished."""
        source = Source(self.data.directory, *((self.dataset.directory, LEROBOT_REPO_ID) if self.dataset else ()))
        own = self.family.keeps_own_progress
        on_checkpoint = self._keep_progress if self.kept is not None and not own else None
        progress = Progress(True, False, keep_progress=self.kept if own else None, on_checkpoint=on_checkpoint)
        if self.teacher is None:
            state = self.family.train_teacher(
                TeacherRun(self.spec, source, self.directory, self.train, VAL_FRACTION, progress)
            )
        else:
            teacher = str(self.teacher.policy_path)
            state = self.family.distill(
                StudentRun(teacher, source, self.directory, self.train, self.distill, self.trainer, None, progress)
            )
        if self.kept is not None:
            self.keep_policy()
        return {"step": state["step"], "wall_time_s": state["wall_time_s"]}  # the tables' training cost

    def keep_policy(self) -> None:
        """Keep the finished run's policy in :attr:`kept` as its family keeps one: what opens on any machine (a
        LeRobot policy folder with its processors and VLM; a built-in checkpoint's policy), stamped with this job."""
        assert self.kept is not None
        self.family.keep_policy(self.directory, self.trainer, self.kept, {"job": record(self), "finished": True})

    def _keep_progress(self, checkpoint: Path) -> None:
        """Make ``checkpoint`` the one kept in :attr:`kept`: all that resuming reads while the run goes on."""
        assert self.kept is not None
        keep_checkpoint(checkpoint, self.kept, {"job": record(self), "finished": False})

    def _kept_checkpoint(self, finished: bool) -> Path | None:
        """The checkpoint kept by a run with the current settings that had (or had not) ``finished``, if any."""
        kept = read_kept(self.kept) if self.kept is not None else None
        if kept is None or kept[1] != {"job": record(self), "finished": finished}:
            return None
        return kept[0]

    def progress(self) -> JobProgress | None:
        """The step of the checkpoint its progress keeps (each one as it is saved): a built-in run's when kept by
        this job, a LeRobot trainer's (which names its run by its own note) when this job has started here."""
        try:
            kept = read_kept(self.kept) if self.kept is not None else None
        except FileNotFoundError:  # its weights archived and not restored: a status reads no progress from it
            return None
        if kept is None or not kept[0].name.startswith(STEP_PREFIX):
            return None
        if kept[1] != {"job": record(self), "finished": False} and not self._lerobot_progress_of_this_run(kept[1]):
            return None
        return JobProgress(int(kept[0].name.removeprefix(STEP_PREFIX)), self.train.steps, "steps")

    def _lerobot_progress_of_this_run(self, note: dict[str, Any]) -> bool:
        """Whether a kept lerobot-train checkpoint's ``note`` is this run's, started here: every training flag of this
        run's settings among its run's flags (another run's progress stays kept until this one saves its own)."""
        if "run" not in note or not is_started(self):
            return False
        from snapflow.training.lerobot_student import lerobot_train_arguments

        return set(lerobot_train_arguments(self.train, None)) <= set(note["run"].get("flags", []))

    def restore_outputs(self) -> bool:
        checkpoint = self._kept_checkpoint(finished=True)
        if checkpoint is None:
            return False
        shutil.rmtree(self.directory, ignore_errors=True)
        self.family.restore_policy(checkpoint, self.directory, self.trainer, self.train)
        return True

    def restore_progress(self) -> bool:
        checkpoint = self._kept_checkpoint(finished=False)
        if checkpoint is None:
            return False
        install_checkpoint(checkpoint, self.directory, self.train.keep_checkpoints)
        return True

    def describe(self) -> str:
        return f"{self.sweep}: train {self.run_name} seed {self.seed}"


__all__ = ["TrainJob"]
