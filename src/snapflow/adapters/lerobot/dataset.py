"""Demonstrations as a LeRobotDataset, written by LeRobot's own writer (``LeRobotDataset.create``, ``add_frame``,
``save_episode``, ``finalize``), so that LeRobot's statistics, loaders and tools read it like any of theirs.

One demonstration is one episode; each frame holds ``observation.state`` (the benchmark's state: Meta-World's full
state, LIBERO's 8-D proprioception), ``observation.images.<camera>`` for each camera whose frames were collected
(stored as images, not video, so no encoder is needed), ``action``, and the task's instruction as the frame's task.
A LIBERO dataset's names and shapes are those LeRobot's ``LiberoEnv`` gives a policy (``image``, ``image2``), so
``lerobot-eval --env.type=libero`` runs a policy trained on it unchanged."""

from __future__ import annotations

import os
import shutil
import tempfile
from pathlib import Path
from typing import Any

from lerobot.datasets.lerobot_dataset import LeRobotDataset
from tqdm.auto import tqdm

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


def lerobot_features(demonstrations: Demonstrations, camera: str) -> dict[str, dict[str, Any]]:
    """The dataset's features in LeRobot's schema (dtype, shape, names)."""
    features = {
        STATE: {"dtype": "float32", "shape": demonstrations.states.shape[1:], "names": None},
        ACTION: {"dtype": "float32", "shape": demonstrations.actions.shape[1:], "names": None},
    }
    for name, frames in camera_frames(demonstrations, camera).items():
        features[name] = {"dtype": "image", "shape": frames.shape[1:], "names": ["height", "width", "channels"]}
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
) -> Path:
    """Write ``demonstrations`` as the LeRobotDataset ``repo_id`` (default ``local/<root's name>``) at ``root``;
    ``camera`` names the main camera's frames (the others carry their own names).

    It is built in a temporary folder beside ``root`` and moved there only once LeRobot has finalised it, so an
    interrupted export leaves no half-written dataset. Returns ``root``."""
    root = check_dataset_root(root)
    if not progress:  # LeRobot's writer maps each episode through Hugging Face datasets, with a bar each
        import datasets

        datasets.disable_progress_bars()
    root.parent.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=f".{root.name}.tmp-", dir=root.parent))
    try:
        dataset = LeRobotDataset.create(
            repo_id=repo_id or f"local/{root.name}",
            fps=fps,
            features=lerobot_features(demonstrations, camera),
            root=staging / "dataset",
            use_videos=False,
            image_writer_threads=0,  # frames are written as they are added: nothing is pending at finalize
            image_writer_processes=0,
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
        if root.exists():  # an empty folder: check_dataset_root allowed it
            root.rmdir()
        os.replace(staging / "dataset", root)
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    return root


__all__ = ["STATE", "ACTION", "IMAGE_PREFIX", "lerobot_features", "check_dataset_root", "write_lerobot_dataset"]
