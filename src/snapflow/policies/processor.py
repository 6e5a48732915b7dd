"""Between an environment and a policy: raw observations in, model inputs out; actions to and from the model's scale.

Every built-in policy has a processor class with this interface; the data, evaluation and benchmark layers use
nothing else of a policy, so they work for every policy in the registry (:mod:`snapflow.policies.factory`).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import torch
from torch import Tensor

from snapflow.errors import InvalidInputError
from snapflow.policies.normalization import NormalizationStats


class Processor(ABC):
    """Mean / std normalisation of the leading ``state_dim`` state entries and of the actions, plus whatever the
    policy makes of the instruction and the image (:meth:`observation`).

    ``instructions`` are the training set's, in order: a processor that encodes instructions by their index (the
    MLP's one-hot) needs them; others ignore them. Both ``stats`` and ``instructions`` are saved in the checkpoint.
    """

    def __init__(self, config: Any, stats: NormalizationStats, instructions: Sequence[str] = ()) -> None:
        self.config = config
        self.stats = stats
        self.instructions = tuple(instructions)
        for name, values, size in (
            ("state", stats.state_mean, self.state_dim),
            ("action", stats.action_mean, config.action_dim),
        ):
            if len(values) != size:
                raise InvalidInputError(
                    f"normalisation stats have {len(values)} {name} dimensions, the policy expects {size}"
                )
        self.state_mean, self.state_std = torch.tensor(stats.state_mean), torch.tensor(stats.state_std)
        self.action_mean, self.action_std = torch.tensor(stats.action_mean), torch.tensor(stats.action_std)

    @classmethod
    @abstractmethod
    def default_config(cls, state_dim: int, action_dim: int, instructions: Sequence[str], **overrides: Any) -> Any:
        """The policy's configuration for data of these dimensions and instructions, with ``overrides`` applied."""

    @classmethod
    @abstractmethod
    def state_entries(cls, config: Any, instructions: Sequence[str]) -> int:
        """How many leading entries of the environment's state vector a policy of ``config`` reads."""

    @classmethod
    def fit(cls, config: Any, demonstrations: Any, episodes: list[int]) -> Processor:
        """The processor of ``config`` with statistics of the given demonstration episodes and all their instructions."""
        instructions = list(demonstrations.instructions.values())
        return cls(config, demonstrations.stats(episodes, cls.state_entries(config, instructions)), instructions)

    @property
    def state_dim(self) -> int:
        return self.state_entries(self.config, self.instructions)

    @property
    def chunk_length(self) -> int:
        return self.config.chunk_length

    @property
    def action_dim(self) -> int:
        return self.config.action_dim

    @property
    def image_size(self) -> int | None:
        """Side of the square camera image the policy reads, or None for a policy without images."""
        return None

    @property
    def extra_cameras(self) -> tuple[str, ...]:
        """The cameras it reads beyond the benchmark's main one, by the benchmark's names (LIBERO's wrist camera,
        ``image2``): :meth:`observation` is given their frames as ``extra_images``. Empty for a policy of one camera."""
        return ()

    def normalized_state(self, states: np.ndarray | Tensor) -> Tensor:
        """The leading ``state_dim`` entries of a batch of raw states (B, >= state_dim), normalised."""
        states = torch.as_tensor(np.asarray(states, dtype=np.float32))
        if states.ndim != 2 or states.shape[1] < self.state_dim:
            raise InvalidInputError(f"states must have shape (batch, >= {self.state_dim}), got {tuple(states.shape)}")
        return (states[:, : self.state_dim] - self.state_mean) / self.state_std

    @abstractmethod
    def observation(
        self,
        states: np.ndarray | Tensor,
        instructions: list[str],
        images: np.ndarray | Tensor | None = None,
        extra_images: Mapping[str, np.ndarray] | None = None,
    ) -> Any:
        """Model input for a batch of raw states (B, >= state_dim), instructions, optional uint8 images (B, S, S, 3)
        of the main camera and, by name, of the :attr:`extra_cameras`."""

    def example_observation(self, batch: int = 1) -> Any:
        """A batch of what the policy reads with neutral values (a zero state, the first instruction it knows, a
        black image where it reads one): for timing and tracing, which the values do not change."""
        images = np.zeros((batch, self.image_size, self.image_size, 3), dtype=np.uint8) if self.image_size else None
        instruction = self.instructions[0] if self.instructions else "push the puck to the goal"
        states = np.zeros((batch, self.state_dim), dtype=np.float32)
        return self.observation(states, [instruction] * batch, images, dict.fromkeys(self.extra_cameras, images))

    def normalize_actions(self, actions: Tensor) -> Tensor:
        return (actions - self.action_mean) / self.action_std

    def unnormalize_actions(self, actions: Tensor) -> Tensor:
        return actions * self.action_std + self.action_mean


__all__ = ["Processor"]
