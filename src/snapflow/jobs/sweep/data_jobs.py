"""A sweep's demonstrations as jobs: one collection a task, the tasks put together, and the LeRobotDataset the
LeRobot runs read.

With ``[data] video``, a task's collection is also its part of that LeRobotDataset, its frames encoded once as video
by LeRobot's writer, and it is kept, packed, beside the sweep's records to be committed as soon as it is collected
(:mod:`snapflow.reporting.packed`, archived in history as weights are): a fresh clone unpacks what is kept (from
history, where it is archived) and collects only the tasks missing. Its demonstrations then hold no frames (the video
holds them), and the LeRobotDataset joins the parts without encoding them again, so that the frames the runs train on
are the kept ones, collected here or elsewhere."""

from __future__ import annotations

import json
import os
import shutil
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, replace
from multiprocessing import get_context
from pathlib import Path
from typing import Any, ClassVar

from snapflow.data.collect import collect
from snapflow.data.demonstrations import META_FILE, Demonstrations
from snapflow.envs.factory import make_benchmark
from snapflow.jobs.runner import Job, record
from snapflow.jobs.sweep.specs import DataSpec
from snapflow.reporting.archive import restore_if_archived
from snapflow.reporting.files import write_json, write_text
from snapflow.reporting.packed import pack_folder, unpack_folder
from snapflow.reporting.records import as_record

RECORD = "job.json"  # a collect or train job's record, inside the folder it fills
LEROBOT_REPO_ID = "local/lerobot"  # the LeRobotDataset's name: it is read from its folder, never from a hub
PART = "lerobot"  # a video collection's part of the LeRobotDataset, inside its folder
RENDERED = "rendered"  # a video collection's demonstrations with their rendered frames, until encoded
PACKED = "demonstrations.tar"  # a video collection kept, packed, beside its ledger record
COLLECTED = "collected.json"  # inside a kept collection: the record of the job that made it
HELD_OUT_FROM = "made_from.json"  # inside a video sweep's held-out frames: the record of the demonstrations they are of
COLLECTING = "collecting.json"  # inside a collection: how long its experts ran


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
    """The expert demonstrations of one task (``data.tasks`` holds it alone), in ``directory``; with ``data.video``
    also its part of the LeRobotDataset (:data:`PART`), kept packed beside ``ledger`` (its committed record)."""

    kind: ClassVar[str] = "collect"
    sweep: str
    directory: Path
    data: DataSpec
    ledger: Path | None = None

    def settings(self) -> dict[str, Any]:
        return as_record(self.data)

    @property
    def ledger_path(self) -> Path | None:
        return self.ledger

    @property
    def packed(self) -> Path | None:
        """Where the collection is kept to be committed (a video collection with a ledger), else None."""
        return self.ledger.parent / PACKED if self.ledger is not None and self.data.video is not None else None

    def run(self) -> dict[str, Any]:
        data, began = self.data, time.perf_counter()
        if (self.directory / META_FILE).is_file():
            # collected whole (meta.json is written last) by a run stopped before its record: the runner keeps a
            # pending job's outputs only where they were made with its settings, so they are this collection's
            Demonstrations.load(self.directory)
            return {} if self.packed is None else self._keep()
        rendered = self.directory / RENDERED if data.video is not None else self.directory
        collecting = self.directory / COLLECTING
        if not (rendered / META_FILE).is_file():
            collect(
                make_benchmark(data.env),
                list(data.tasks),
                data.episodes_per_task,
                rendered,
                data.image_size,
                progress=False,
                extra_cameras=data.extra_cameras,
                action_noise=data.action_noise,
            )
            write_json(collecting, {"seconds": time.perf_counter() - began})  # a run stopped after it still knows
        if data.video is None:
            return {"wall_time_s": time.perf_counter() - began}
        encoding = time.perf_counter()
        results: dict[str, Any] = {"frame_error": self._encode(Demonstrations.load(rendered))}
        shutil.rmtree(rendered)
        if collecting.is_file():  # the collection's time and the encoding's: what the status estimates from
            collected = json.loads(collecting.read_text())["seconds"]
            results["wall_time_s"] = collected + time.perf_counter() - encoding
        return {**results, **(self._keep() if self.packed is not None else {})}

    def _encode(self, demonstrations: Demonstrations) -> dict[str, Any]:
        """Write the task's LeRobotDataset part with its frames as video, then its demonstrations without frames
        (meta.json last: the collection is whole); returns the frames' error against the rendered ones."""
        from snapflow.adapters.lerobot.dataset import video_frame_error, write_lerobot_dataset

        benchmark = make_benchmark(self.data.env)
        part = self.directory / PART
        shutil.rmtree(part, ignore_errors=True)  # an interrupted write: LeRobot's writer wants a new folder
        write_lerobot_dataset(
            demonstrations, part, LEROBOT_REPO_ID, benchmark.fps, benchmark.camera, False, self.data.video
        )
        error = video_frame_error(part, demonstrations, benchmark.camera)
        replace(demonstrations, images=None, extra_images={}).save(self.directory)
        return error

    def _keep(self) -> dict[str, Any]:
        """Pack the collection beside its ledger record, with the record of this job inside (what a restore
        checks); returns its size."""
        assert self.packed is not None
        write_json(self.directory / COLLECTED, record(self))
        return {"packed_bytes": pack_folder(self.directory, self.packed).stat().st_size}

    def restore_outputs(self) -> bool:
        """Unpack the kept collection (from history where it is archived there) if this job's settings made it."""
        if self.packed is None or not (self.packed.is_file() or restore_if_archived(self.packed)):
            return False
        unpack_folder(self.packed, self.directory)
        try:
            made_by = json.loads((self.directory / COLLECTED).read_text())
        except (FileNotFoundError, json.JSONDecodeError):
            made_by = None
        if made_by != record(self):  # another collection's pack: collected again, never mixed in
            shutil.rmtree(self.directory)
            return False
        return True

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
        if self.data.data.video is not None:
            self._from_video()
            return {}
        benchmark = make_benchmark(self.data.data.env)
        demonstrations = Demonstrations.load(self.data.directory)
        write_lerobot_dataset(
            demonstrations, self.directory, LEROBOT_REPO_ID, benchmark.fps, benchmark.camera, progress=False
        )
        return {}

    def _from_video(self) -> None:
        """The tasks' frames decoded from their kept video and written as PNG, a part a task, then joined: decoding
        one frame of video at random, as training draws them, took 8.3 ms against 1.5 ms for a PNG (two 64-px
        cameras), which would have nearly doubled a SmolVLA's training step on the CPU. The frames trained on are
        the kept ones wherever they were collected. The parts are written a process a core: LeRobot's writer
        (PNG encoding, its parquet, its statistics) runs on one, and took 49 min for the four suites alone."""
        from snapflow.adapters.lerobot.dataset import merge_lerobot_datasets

        staging = self.directory.with_name(f".{self.directory.name}.parts")
        shutil.rmtree(staging, ignore_errors=True)
        parts = [staging / str(index) for index in range(len(self.data.parts))]
        data = self.data.data
        workers = max(1, min(len(parts), len(os.sched_getaffinity(0))))
        with ProcessPoolExecutor(workers, mp_context=get_context("spawn")) as pool:
            written = [
                pool.submit(_write_part, data.env, data.extra_cameras, collected.directory, part)
                for collected, part in zip(self.data.parts, parts, strict=True)
            ]
            for future in written:
                future.result()  # a part's error, raised here
        merge_lerobot_datasets(parts, self.directory, LEROBOT_REPO_ID)
        shutil.rmtree(staging)

    def describe(self) -> str:
        return f"{self.sweep}: demonstrations as a LeRobotDataset"


def held_out_with_frames(data: DataJob, val_fraction: float) -> Path | None:
    """A video sweep's held-out demonstrations (each task's last ``val_fraction`` of episodes, as
    :meth:`~snapflow.data.demonstrations.Demonstrations.split` holds them out of the whole set) with their frames
    decoded from each task's kept video, written once beside the sweep's demonstrations, which hold no frames: what
    an evaluation's offline metrics read (the whole set's frames decoded would take ~12 GB for the four LIBERO suites,
    its held-out ones a tenth of that). Written anew where the demonstrations were made again since; None where no
    episode is held out."""
    from snapflow.adapters.lerobot.dataset import with_decoded_frames

    directory = data.directory.with_name(f"{data.directory.name}-held-out-{val_fraction:g}")
    made_from = (data.directory / RECORD).read_text()  # the demonstrations' record: which ones these came from
    if (directory / META_FILE).is_file() and (directory / HELD_OUT_FROM).is_file():
        if (directory / HELD_OUT_FROM).read_text() == made_from:
            return directory
    shutil.rmtree(directory, ignore_errors=True)
    benchmark = make_benchmark(data.data.env)
    cameras = list(benchmark.check_cameras(data.data.extra_cameras))
    parts = []
    for part in data.parts:  # a task a part, so its split is the whole set's on that task
        demonstrations = Demonstrations.load(part.directory)
        _, held_out = demonstrations.split(val_fraction)
        if held_out:
            decoded = with_decoded_frames(demonstrations, part.directory / PART, benchmark.camera, cameras)
            parts.append(decoded.select(held_out))
    if not parts:
        return None
    write_text(directory / HELD_OUT_FROM, made_from)
    Demonstrations.concatenate(parts).save(directory)  # its meta written last: a cut write is written again
    return directory


def _write_part(env: str, extra_cameras: tuple[str, ...] | None, collected: Path, part: Path) -> None:
    """One task's kept collection, its frames decoded from its video, written as a LeRobotDataset at ``part``."""
    from snapflow.adapters.lerobot.dataset import with_decoded_frames, write_lerobot_dataset

    benchmark = make_benchmark(env)
    cameras = list(benchmark.check_cameras(extra_cameras))
    demonstrations = with_decoded_frames(Demonstrations.load(collected), collected / PART, benchmark.camera, cameras)
    write_lerobot_dataset(demonstrations, part, LEROBOT_REPO_ID, benchmark.fps, benchmark.camera, False)


__all__ = [
    "RECORD",
    "LEROBOT_REPO_ID",
    "PART",
    "PACKED",
    "FolderJob",
    "CollectJob",
    "DataJob",
    "LeRobotDatasetJob",
    "held_out_with_frames",
]
