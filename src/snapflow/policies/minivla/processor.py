"""Turns raw observations (state, instruction, image) into MiniVLA inputs, and actions to / from its scale."""

from __future__ import annotations

import re
import zlib

import numpy as np
import torch
from torch import Tensor

from snapflow.data.demonstrations import NormalizationStats
from snapflow.policies.minivla.configuration import MiniVLAConfig


class MiniVLAProcessor:
    """Hashed word tokenizer + mean/std normalisation from the training demonstrations."""

    def __init__(self, config: MiniVLAConfig, stats: NormalizationStats) -> None:
        for name, values, size in (("state", stats.state_mean, config.state_dim), ("action", stats.action_mean, config.action_dim)):
            if len(values) != size:
                raise ValueError(f"normalisation stats have {len(values)} {name} dimensions, the policy expects {size}")
        self.config = config
        self.stats = stats
        self.state_mean, self.state_std = torch.tensor(stats.state_mean), torch.tensor(stats.state_std)
        self.action_mean, self.action_std = torch.tensor(stats.action_mean), torch.tensor(stats.action_std)

    def tokenize(self, instructions: list[str]) -> tuple[Tensor, Tensor]:
        """Word ids in [1, vocab) by a stable hash (0 pads), truncated to ``max_instruction_tokens``."""
        tokens = torch.zeros(len(instructions), self.config.max_instruction_tokens, dtype=torch.long)
        for row, text in enumerate(instructions):
            words = re.findall(r"[a-z0-9]+", text.lower())[: self.config.max_instruction_tokens]
            ids = [1 + zlib.crc32(word.encode()) % (self.config.vocab_size - 1) for word in words]
            tokens[row, : len(ids)] = torch.tensor(ids, dtype=torch.long)
        return tokens, tokens != 0

    def observation(self, states: np.ndarray | Tensor, instructions: list[str], images: np.ndarray | Tensor | None = None) -> dict[str, Tensor]:
        """Batch of raw states (B, >= state_dim; the leading state_dim entries are read), instructions and
        optional uint8 images (B, S, S, 3)."""
        states = torch.as_tensor(np.asarray(states, dtype=np.float32))
        if states.ndim != 2 or states.shape[1] < self.config.state_dim:
            raise ValueError(f"states must have shape (batch, >= {self.config.state_dim}), got {tuple(states.shape)}")
        states = states[:, : self.config.state_dim]
        tokens, token_mask = self.tokenize(instructions)
        batch = {"state": (states - self.state_mean) / self.state_std, "tokens": tokens, "token_mask": token_mask}
        if self.config.use_image:
            if images is None:
                raise ValueError("this policy was configured with use_image=True, so every observation needs an image")
            batch["image"] = torch.as_tensor(np.asarray(images)).permute(0, 3, 1, 2).float() / 255.0
        return batch

    def normalize_actions(self, actions: Tensor) -> Tensor:
        return (actions - self.action_mean) / self.action_std

    def unnormalize_actions(self, actions: Tensor) -> Tensor:
        return actions * self.action_std + self.action_mean
