"""Demonstrations as a LeRobotDataset, written by LeRobot's own writer (``LeRobotDataset.create``, ``add_frame``,
``save_episode``, ``finalize``), so that LeRobot's statistics, loaders and tools read it like any of theirs.

One demonstration is one episode; each frame holds ``observation.state`` (the benchmark's state: Meta-World's full
state, LIBERO's 8-D proprioception), ``observation.images.<camera>`` for each camera whose frames were collected
(stored as PNG images, or with ``video`` as video through LeRobot's encoder: a LIBERO frame of 64 px is ~6 KB as PNG,
~0.2 KB as AV1), ``action``, and the task's instruction as the frame's task.
A LIBERO dataset's names and shapes are those LeRobot's ``LiberoEnv`` gives a policy (``image``, ``image2``), so
``lerobot-eval --env.type=libero`` runs a policy trained on it unchanged."""

from __future__ import annotations

import os
import shutil
import tempfile
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import replace
from pathlib import Path
from typing import Any

from lerobot.datasets.lerobot_dataset import LeRobotDataset
from tqdm.auto import tqdm

from snapflow.adapters.lerobot.video import check_video_lengths, decoded_frames, encoder_options, frame_error
from snapflow.adapters.lerobot_config import VIDEO_BACKEND, VideoEncoding
from snapflow.data.demonstrations import Demonstrations

STATE = "observation.state"
ACTION = "action"
IMAGE_PREFIX = "observation.images."


def camera_frames(demonstrations: Demonstrations, camera: str) -> dict[str, Any]:
    """Each camera's frames by its feature name: ``camera`` names the main one, the others carry their own names."""
    if demonstrations.images is None:
        return {}
    cameras = {camera: demonstrations.images, **demonstrations.extra_images}
    return {IMAGE_PREFIX + name: frames for name, frames in cameras.items()}


def lerobot_features(demonstrations: Demonstrations, camera: str, video: bool = False) -> dict[str, dict[str, Any]]:
    """The dataset's features in LeRobot's schema (dtype, shape, names); frames as ``video`` or images."""
    features = {
        STATE: {"dtype": "float32", "shape": demonstrations.states.shape[1:], "names": None},
        ACTION: {"dtype": "float32", "shape": demonstrations.actions.shape[1:], "names": None},
    }
    for name, frames in camera_frames(demonstrations, camera).items():
        features[name] = {
            "dtype": "video" if video else "image",
            "shape": frames.shape[1:],
            "names": ["height", "width", "channels"],
        }
    return features


def policy_features(dataset_features: dict[str, dict[str, Any]]) -> dict[str, Any]:
    """A dataset's features as LeRobot's ``PolicyFeature`` (LeRobot's own conversion, which 0.6 moved out of
    ``lerobot.datasets.utils``)."""
    try:
        from lerobot.utils.feature_utils import dataset_to_policy_features
    except ImportError:  # LeRobot < 0.6
        from lerobot.datasets.utils import dataset_to_policy_features
    return dataset_to_policy_features(dataset_features)


def check_dataset_root(root: str | Path) -> Path:
    """Refuse a root that already holds something: a dataset is written once, never over another."""
    root = Path(root)
    if root.exists() and (not root.is_dir() or any(root.iterdir())):
        raise FileExistsError(f"{root} already exists and is not empty; choose another LeRobotDataset root")
    return root


def write_lerobot_dataset(
    demonstrations: Demonstrations,
    root: str | Path,
    repo_id: str | None = None,
    fps: int = 80,
    camera: str = "camera",
    progress: bool = True,
    video: VideoEncoding | None = None,
) -> Path:
    """Write ``demonstrations`` as the LeRobotDataset ``repo_id`` (default ``local/<root's name>``) at ``root``;
    ``camera`` names the main camera's frames (the others carry their own names); ``video``: how LeRobot's encoder
    keeps the frames as video (every episode's frames checked to be all there), else they are stored as PNG images.

    It is built in a temporary folder beside ``root`` and moved there only once LeRobot has finalised it, so an
    interrupted export leaves no half-written dataset. Returns ``root``."""
    if not progress:  # LeRobot's writer maps each episode through Hugging Face datasets, with a bar each
        import datasets

        datasets.disable_progress_bars()
    with _built_beside(root) as built:
        dataset = LeRobotDataset.create(
            repo_id=repo_id or f"local/{Path(root).name}",
            fps=fps,
            features=lerobot_features(demonstrations, camera, video is not None),
            root=built,
            use_videos=video is not None,
            video_backend=VIDEO_BACKEND,  # LeRobot would try torchcodec first: a long traceback without FFmpeg
            image_writer_threads=0,  # frames are written as they are added: nothing is pending at finalize
            image_writer_processes=0,
            **(encoder_options(video) if video is not None else {}),
        )
        cameras = camera_frames(demonstrations, camera)
        for episode in tqdm(demonstrations.episodes, desc="writing the LeRobotDataset", disable=not progress):
            instruction = demonstrations.instructions[episode.task]
            for row in range(episode.start, episode.start + episode.length):
                frame = {STATE: demonstrations.states[row], ACTION: demonstrations.actions[row], "task": instruction}
                frame.update({name: frames[row] for name, frames in cameras.items()})
                dataset.add_frame(frame)
            dataset.save_episode()
        dataset.finalize()
        if video is not None:
            check_video_lengths(built, fps)
    return Path(root)


def merge_lerobot_datasets(parts: Sequence[str | Path], root: str | Path, repo_id: str) -> Path:
    """The LeRobotDatasets at ``parts`` as one, ``repo_id`` at ``root``, by LeRobot's own ``aggregate_datasets``:
    episodes in the parts' order, statistics aggregated, files joined as they are (PNG frames copied; video files
    joined without encoding their frames again). Built beside ``root`` and moved there whole."""
    from lerobot.datasets.aggregate import aggregate_datasets

    paths = [Path(part) for part in parts]
    names = [f"local/part-{index}" for index in range(len(paths))]
    with _built_beside(root) as built:
        aggregate_datasets(names, repo_id, roots=paths, aggr_root=built)
    return Path(root)


def video_frame_error(root: str | Path, demonstrations: Demonstrations, camera: str) -> dict[str, dict[str, Any]]:
    """How far each camera's frames, as the video dataset at ``root`` decodes them, are from the rendered ones in
    ``demonstrations`` (:func:`~snapflow.adapters.lerobot.video.frame_error`), by feature name."""
    return {
        name: frame_error(decoded_frames(root, name), rendered)
        for name, rendered in camera_frames(demonstrations, camera).items()
    }


def with_decoded_frames(
    demonstrations: Demonstrations, root: str | Path, camera: str, cameras: list[str]
) -> Demonstrations:
    """``demonstrations`` (held without frames) with the frames of the video dataset at ``root`` decoded back:
    ``camera`` the main one, ``cameras`` the others."""
    decoded = {name: decoded_frames(root, IMAGE_PREFIX + name) for name in [camera, *cameras]}
    return replace(demonstrations, images=decoded.pop(camera), extra_images=decoded)


@contextmanager
def _built_beside(root: str | Path) -> Iterator[Path]:
    """A folder to build a dataset in, beside ``root`` (which :func:`check_dataset_root` must allow), put at ``root``
    only once the block ends without error: an interrupted build leaves no half-written dataset."""
    root = check_dataset_root(root)
    root.parent.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=f".{root.name}.tmp-", dir=root.parent))
    try:
        yield staging / "dataset"
        if root.exists():  # an empty folder there is replaced
            root.rmdir()
        os.replace(staging / "dataset", root)
    finally:
        shutil.rmtree(staging, ignore_errors=True)


__all__ = [
    "STATE",
    "ACTION",
    "IMAGE_PREFIX",
    "lerobot_features",
    "check_dataset_root",
    "write_lerobot_dataset",
    "merge_lerobot_datasets",
    "video_frame_error",
    "with_decoded_frames",
]
