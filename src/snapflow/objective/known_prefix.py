"""Any objective with real-time chunking trained in: each row's first actions given as known (LeRobot's
training-time RTC), so that the one-step jump learns to continue a prefix rather than have it inpainted after.

Per row, a delay d is drawn uniformly from 0..``max_delay``; the row's first d ground-truth actions ride clean, at
time 0, through every pass of the wrapped objective (its flow-matching rows, its no-grad targets and its one-step
rows alike: :class:`~snapflow.flow.known_prefix.KnownPrefixPolicy`), and its losses weigh the rest of the chunk only.
SnapFlow's two-step target is then the model's own prefix-conditioned field, which its flow-matching rows keep
learning: the same self-distillation, given the prefix.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import torch
from torch import Tensor

from snapflow.errors import InvalidInputError
from snapflow.flow.known_prefix import KnownPrefixPolicy, draw_delays, prefix_mask
from snapflow.objective.base import LossOutput, TwoBranchObjective, draw_device
from snapflow.protocol import FlowPolicy


@dataclass(frozen=True)
class KnownPrefixObjective:
    """``objective`` with each row's first 0..``max_delay`` actions known (drawn per row from the generator)."""

    objective: TwoBranchObjective
    max_delay: int

    def __post_init__(self) -> None:
        if self.max_delay < 1:
            raise InvalidInputError(
                f"real-time chunking trained in needs a largest delay of 1 or more, got {self.max_delay}"
            )
        if self.objective.copies_policy:
            raise InvalidInputError(
                f"{type(self.objective).__name__} keeps a copy of the policy, which a known prefix cannot condition"
            )

    def __getattr__(self, name: str) -> Any:  # alpha, lambda, the time sampler, the schedule: the objective's own
        if name == "objective":  # not set yet (a copy being built): no recursion
            raise AttributeError(name)
        return getattr(self.objective, name)

    def __call__(
        self,
        policy: FlowPolicy,
        observation: Any,
        actions: Tensor,
        *,
        generator: torch.Generator | None = None,
        **kwargs: Any,
    ) -> LossOutput:
        """The objective's loss on ``actions`` (B, chunk length, width) with each row's known prefix drawn first;
        ``kwargs`` (noise, time, progress) are the objective's."""
        if actions.ndim != 3 or self.max_delay >= actions.shape[1]:
            raise InvalidInputError(
                f"a largest delay of {self.max_delay} needs chunks of more actions, got chunks {tuple(actions.shape)}"
            )
        delays = draw_delays(actions.shape[0], self.max_delay, generator, draw_device(generator, actions.device))
        mask = prefix_mask(delays.to(actions.device), actions.shape[1])
        conditioned = KnownPrefixPolicy(policy, actions, mask)
        return self.objective(conditioned, observation, actions, generator=generator, **kwargs)


__all__ = ["KnownPrefixObjective"]
