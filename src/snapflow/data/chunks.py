"""Every (observation, action chunk) pair of a set of demonstration episodes, held as tensors."""

from __future__ import annotations

from typing import Any

import numpy as np
import torch
from torch import Tensor

from snapflow.data.demonstrations import Demonstrations
from snapflow.errors import InvalidInputError
from snapflow.policies.processor import Processor


def chunk_rows(demonstrations: Demonstrations, rows: np.ndarray, length: int) -> np.ndarray:
    """For each row, the rows of the ``length`` actions from it on, the episode's last repeated past its end."""
    ends = np.array([e.start + e.length for e in demonstrations.episodes])[demonstrations.episode_index[rows]]
    return np.minimum(rows[:, None] + np.arange(length)[None, :], ends[:, None] - 1)


class ChunkData:
    """Sample i: the observation at one step and the next ``chunk_length`` actions, the last repeated
    past the episode's end (the robot holds its final command). Observations and actions are normalised.

    Observations are made a batch at a time from the demonstrations' arrays: camera frames stay uint8 (and
    memory-mapped, as loaded), so a suite of 128-px frames is never held in memory as floats."""

    def __init__(self, demonstrations: Demonstrations, episodes: list[int], processor: Processor) -> None:
        if not episodes:
            raise InvalidInputError("no episodes selected")
        if (
            demonstrations.states.shape[1] < processor.state_dim
            or demonstrations.actions.shape[1] != processor.action_dim
        ):
            raise InvalidInputError(
                f"demonstrations have state/action dims {demonstrations.states.shape[1]}/{demonstrations.actions.shape[1]}, "
                f"the policy reads {processor.state_dim} state entries and writes {processor.action_dim} action dims"
            )
        size = processor.image_size
        if size and demonstrations.images is None:
            raise InvalidInputError(
                "the policy uses images but the demonstrations hold none; collect with --image-size"
            )
        if size and demonstrations.images.shape[1:3] != (size, size):
            raise InvalidInputError(
                f"the demonstrations' images are {demonstrations.images.shape[1]}x{demonstrations.images.shape[2]}, "
                f"the policy expects {size}x{size}"
            )
        missing = [name for name in processor.extra_cameras if name not in demonstrations.extra_images]
        if missing:
            raise InvalidInputError(f"the policy reads cameras {missing} that the demonstrations hold no frames of")
        self.demonstrations, self.processor = demonstrations, processor
        self.rows = demonstrations.rows(episodes)
        following = chunk_rows(demonstrations, self.rows, processor.chunk_length)
        self.actions = processor.normalize_actions(torch.from_numpy(demonstrations.actions[following]))
        self.instructions = [
            demonstrations.instructions[demonstrations.episodes[e].task]
            for e in demonstrations.episode_index[self.rows]
        ]

    def __len__(self) -> int:
        return len(self.actions)

    def batch(self, indices: Tensor) -> tuple[Any, Tensor]:
        """The observations (model inputs) and normalised action chunks of samples ``indices``."""
        indices = indices.numpy()
        rows, demonstrations = self.rows[indices], self.demonstrations
        images = demonstrations.images[rows] if self.processor.image_size else None
        extra = {name: demonstrations.extra_images[name][rows] for name in self.processor.extra_cameras}
        observation = self.processor.observation(
            demonstrations.states[rows], [self.instructions[index] for index in indices], images, extra
        )
        return observation, self.actions[torch.from_numpy(indices)]


def split_chunk_data(
    demonstrations: Demonstrations, processor: Processor, val_fraction: float
) -> tuple[ChunkData, ChunkData | None]:
    """Training and held-out chunks: the last ``val_fraction`` of each task's episodes are held out."""
    train_episodes, val_episodes = demonstrations.split(val_fraction)
    return ChunkData(demonstrations, train_episodes, processor), ChunkData(
        demonstrations, val_episodes, processor
    ) if val_episodes else None


__all__ = ["ChunkData", "chunk_rows", "split_chunk_data"]
