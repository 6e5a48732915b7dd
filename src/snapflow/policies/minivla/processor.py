"""Turns raw observations (state, instruction, image) into MiniVLA inputs, and actions to / from its scale."""

from __future__ import annotations

import re
import zlib
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import torch
from torch import Tensor

from snapflow.errors import InvalidInputError
from snapflow.policies.minivla.configuration import MiniVLAConfig
from snapflow.policies.processor import Processor


class MiniVLAProcessor(Processor):
    """Hashed word tokenizer + mean/std normalisation from the training demonstrations."""

    config: MiniVLAConfig

    @classmethod
    def state_entries(cls, config: MiniVLAConfig, instructions: Sequence[str]) -> int:
        return config.state_dim

    @classmethod
    def default_config(
        cls, state_dim: int, action_dim: int, instructions: Sequence[str], **overrides: Any
    ) -> MiniVLAConfig:
        """MiniVLA's default sizes, reading ``state_dim`` state entries and writing ``action_dim`` actions."""
        return MiniVLAConfig(**{"state_dim": state_dim, "action_dim": action_dim, **overrides})

    @property
    def image_size(self) -> int | None:
        return self.config.image_size if self.config.use_image else None

    @property
    def extra_cameras(self) -> tuple[str, ...]:
        return self.config.extra_cameras if self.config.use_image else ()

    def tokenize(self, instructions: list[str]) -> tuple[Tensor, Tensor]:
        """Word ids in [1, vocab) by a stable hash (0 pads), truncated to ``max_instruction_tokens``."""
        tokens = torch.zeros(len(instructions), self.config.max_instruction_tokens, dtype=torch.long)
        for row, text in enumerate(instructions):
            words = re.findall(r"[a-z0-9]+", text.lower())[: self.config.max_instruction_tokens]
            ids = [1 + zlib.crc32(word.encode()) % (self.config.vocab_size - 1) for word in words]
            tokens[row, : len(ids)] = torch.tensor(ids, dtype=torch.long)
        return tokens, tokens != 0

    def observation(
        self,
        states: np.ndarray | Tensor,
        instructions: list[str],
        images: np.ndarray | Tensor | None = None,
        extra_images: Mapping[str, np.ndarray] | None = None,
    ) -> dict[str, Tensor]:
        tokens, token_mask = self.tokenize(instructions)
        batch = {"state": self.normalized_state(states), "tokens": tokens, "token_mask": token_mask}
        if self.config.use_image:
            if images is None:
                raise InvalidInputError(
                    "this policy was configured with use_image=True, so every observation needs an image"
                )
            frames = {
                "image": images,
                **{f"image.{name}": (extra_images or {}).get(name) for name in self.extra_cameras},
            }
            for key, value in frames.items():
                if value is None:
                    raise InvalidInputError(
                        f"this policy reads camera {key.removeprefix('image.')!r}; no frames were given"
                    )
                batch[key] = torch.as_tensor(np.asarray(value, dtype=np.uint8)).permute(0, 3, 1, 2).contiguous()
        return batch
