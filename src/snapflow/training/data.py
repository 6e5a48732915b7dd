"""Every (observation, action chunk) pair of a set of demonstration episodes, held as tensors."""

from __future__ import annotations

import numpy as np
import torch
from torch import Tensor

from snapflow.data.demonstrations import Demonstrations
from snapflow.policies.minivla import MiniVLAProcessor


class ChunkData:
    """Sample i: the observation at one step and the next ``chunk_length`` actions, the last repeated
    past the episode's end (the robot holds its final command). Observations and actions are normalised."""

    def __init__(self, demonstrations: Demonstrations, episodes: list[int], processor: MiniVLAProcessor) -> None:
        if not episodes:
            raise ValueError("no episodes selected")
        config = processor.config
        if demonstrations.states.shape[1] < config.state_dim or demonstrations.actions.shape[1] != config.action_dim:
            raise ValueError(
                f"demonstrations have state/action dims {demonstrations.states.shape[1]}/{demonstrations.actions.shape[1]}, "
                f"the policy reads {config.state_dim} state entries and writes {config.action_dim} action dims"
            )
        if config.use_image and demonstrations.images is None:
            raise ValueError("the policy uses images but the demonstrations hold none; collect with --image-size")
        if config.use_image and demonstrations.images.shape[1:3] != (config.image_size, config.image_size):
            raise ValueError(f"the demonstrations' images are {demonstrations.images.shape[1]}x{demonstrations.images.shape[2]}, "
                             f"the policy expects {config.image_size}x{config.image_size}")
        rows = demonstrations.rows(episodes)
        ends = np.concatenate([np.full(demonstrations.episodes[e].length, demonstrations.episodes[e].start + demonstrations.episodes[e].length) for e in episodes])
        chunk_rows = np.minimum(rows[:, None] + np.arange(config.chunk_length)[None, :], ends[:, None] - 1)
        self.actions = processor.normalize_actions(torch.from_numpy(demonstrations.actions[chunk_rows]))
        instructions = [demonstrations.instructions[demonstrations.episodes[e].task] for e in demonstrations.episode_index[rows]]
        images = demonstrations.images[rows] if config.use_image else None
        self.observation = processor.observation(demonstrations.states[rows], instructions, images)

    def __len__(self) -> int:
        return len(self.actions)

    def batch(self, indices: Tensor) -> tuple[dict[str, Tensor], Tensor]:
        return {key: value[indices] for key, value in self.observation.items()}, self.actions[indices]
