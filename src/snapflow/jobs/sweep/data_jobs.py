"""A sweep's demonstrations as jobs: one collection a task, the tasks put together, and the LeRobotDataset the
LeRobot runs read."""

from __future__ import annotations

import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

from snapflow.data.collect import collect
from snapflow.data.demonstrations import META_FILE, Demonstrations
from snapflow.envs.factory import make_benchmark
from snapflow.jobs.runner import Job
from snapflow.jobs.sweep.specs import DataSpec
from snapflow.reporting.records import as_record

RECORD = "job.json"  # a collect or train job's record, inside the folder it fills
LEROBOT_REPO_ID = "local/lerobot"  # the LeRobotDataset's name: it is read from its folder, never from a hub


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
        if (self.directory / META_FILE).is_file():
            # collected whole (meta.json is written last) by a run stopped before its record: the runner keeps a
            # pending job's outputs only where they were made with its settings, so they are this collection's
            Demonstrations.load(self.directory)
            return {}
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


__all__ = ["RECORD", "LEROBOT_REPO_ID", "FolderJob", "CollectJob", "DataJob", "LeRobotDatasetJob"]
