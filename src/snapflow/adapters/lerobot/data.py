"""Training pairs from a LeRobotDataset, run through the policy's own LeRobot pre-processor."""

from __future__ import annotations

from typing import Any

import numpy as np
import torch
from torch import Tensor
from torch.utils.data import default_collate

from snapflow.adapters.lerobot.base import LeRobotFlowPolicy


class ActionChunks:
    """A LeRobotDataset's frames, each with its next ``chunk_size`` actions: the item LeRobot's own
    ``delta_timestamps={"action": [0, 1/fps, ...]}`` gives (the chunk clamped to the frame's episode, its last action
    repeated, ``action_is_pad`` marking the repeats), its chunk read from the actions held in memory.

    LeRobot 0.6 reads a chunk's rows with every column, so each frame decoded its cameras' PNGs once per chunk step
    (18 images a frame for 8 actions and two cameras: 70% of a small SmolVLA's training step on a CPU); here each
    frame decodes its own images alone. ``dataset``: a LeRobotDataset without ``delta_timestamps``.
    """

    def __init__(self, dataset: Any, chunk_size: int) -> None:
        if dataset.delta_timestamps is not None:
            raise ValueError("ActionChunks builds the chunks itself: give it a LeRobotDataset without delta_timestamps")
        self.dataset, self.chunk_size = dataset, chunk_size
        table = dataset.hf_dataset.data  # the loaded episodes' rows, as Arrow columns
        actions = table.column("action").combine_chunks()
        self.actions = np.asarray(actions.flatten(), dtype=np.float32).reshape(len(actions), -1)
        self.row_of = {int(index): row for row, index in enumerate(table.column("index").to_numpy())}

    def __len__(self) -> int:
        return len(self.dataset)

    def __getitem__(self, position: int) -> dict[str, Any]:
        item = self.dataset[position]
        frame, episode = int(item["index"]), self.dataset.meta.episodes[int(item["episode_index"])]
        wanted = frame + np.arange(self.chunk_size)
        last = episode["dataset_to_index"] - 1
        rows = [self.row_of[index] for index in np.minimum(wanted, last)]
        item["action"] = torch.from_numpy(self.actions[rows])
        item["action_is_pad"] = torch.from_numpy(wanted > last)
        return item


class LeRobotChunkData:
    """``batch(indices)`` -> (pre-processed batch, padded action chunk), the interface the trainer draws from.

    The dataset must yield action chunks (``delta_timestamps`` on ``action``) of the policy's chunk size.
    """

    def __init__(self, dataset: Any, preprocessor: Any, adapter: LeRobotFlowPolicy) -> None:
        self.dataset, self.preprocessor, self.adapter = dataset, preprocessor, adapter

    def __len__(self) -> int:
        return len(self.dataset)

    def batch(self, indices: Tensor) -> tuple[dict[str, Any], Tensor]:
        batch = self.preprocessor(default_collate([self.dataset[int(index)] for index in indices]))
        return batch, self.adapter.action_targets(batch)
