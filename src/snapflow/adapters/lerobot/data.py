"""Training pairs from a LeRobotDataset, run through the policy's own LeRobot pre-processor."""

from __future__ import annotations

from typing import Any

from torch import Tensor, nn
from torch.utils.data import default_collate


class LeRobotChunkData:
    """``batch(indices)`` -> (pre-processed batch, padded action chunk), the interface the trainer draws from.

    The dataset must yield action chunks (``delta_timestamps`` on ``action``) of the policy's chunk size.
    """

    def __init__(self, dataset: Any, preprocessor: Any, policy: nn.Module) -> None:
        self.dataset, self.preprocessor, self.policy = dataset, preprocessor, policy

    def __len__(self) -> int:
        return len(self.dataset)

    def batch(self, indices: Tensor) -> tuple[dict[str, Any], Tensor]:
        batch = self.preprocessor(default_collate([self.dataset[int(index)] for index in indices]))
        return batch, self.policy.prepare_action(batch)
