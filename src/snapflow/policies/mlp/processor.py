"""The MLP policy on an environment: normalised state entries followed by a one-hot of the task's instruction."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import torch
from torch import Tensor

from snapflow.errors import InvalidInputError
from snapflow.policies.mlp.configuration import MLPPolicyConfig
from snapflow.policies.processor import Processor


class MLPProcessor(Processor):
    """``observation_dim`` = the leading state entries read + one entry per training instruction."""

    config: MLPPolicyConfig

    def __init__(self, config: MLPPolicyConfig, stats: Any, instructions: Sequence[str] = ()) -> None:
        if not instructions or config.observation_dim <= len(instructions):
            raise InvalidInputError(
                f"an MLP policy on an environment reads state entries and a one-hot of {len(instructions)} instruction(s): "
                f"observation_dim {config.observation_dim} leaves no state entry"
            )
        super().__init__(config, stats, instructions)
        self._index = {text: index for index, text in enumerate(self.instructions)}

    @classmethod
    def state_entries(cls, config: MLPPolicyConfig, instructions: Sequence[str]) -> int:
        return config.observation_dim - len(instructions)

    @classmethod
    def default_config(
        cls, state_dim: int, action_dim: int, instructions: Sequence[str], **overrides: Any
    ) -> MLPPolicyConfig:
        """All state entries and one-hot instructions in, chunks of 8 actions out, 512-wide layers."""
        return MLPPolicyConfig(
            **{
                "observation_dim": state_dim + len(instructions),
                "action_dim": action_dim,
                "chunk_length": 8,
                "hidden_dim": 512,
                **overrides,
            }
        )

    def observation(
        self,
        states: np.ndarray | Tensor,
        instructions: list[str],
        images: np.ndarray | Tensor | None = None,
        extra_images: Mapping[str, np.ndarray] | None = None,
    ) -> Tensor:
        unknown = sorted(set(instructions) - set(self._index))
        if unknown:
            raise InvalidInputError(
                f"the MLP policy was trained on the instructions {list(self.instructions)}; it cannot read {unknown}"
            )
        one_hot = torch.zeros(len(instructions), len(self.instructions))
        one_hot[
            torch.arange(len(instructions)),
            torch.tensor([self._index[text] for text in instructions], dtype=torch.long),
        ] = 1.0
        return torch.cat([self.normalized_state(states), one_hot], dim=1)
