"""Euler sampling from t = 1 (noise) to t = 0 (actions), for any number of function evaluations.

One network serves every mode: the N-step teacher asks for the instantaneous velocity at each step
(s = t); SnapFlow asks for the average velocity of each jump (s = the next grid time), so SnapFlow 1-NFE
is a single jump from t = 1 to s = 0. Naive 1-NFE is the teacher run with one step (s = t = 1).
"""

from __future__ import annotations

import re
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import torch
from torch import Tensor

from snapflow.flow.path import euler_step
from snapflow.protocol import FlowPolicy

VelocityFn = Callable[[Tensor, Tensor, Tensor], Tensor]
"""``velocity(x_t, t, s)`` with the context already bound."""


@dataclass(frozen=True)
class SamplingMode:
    """How many Euler steps to take and which target time to ask the network for.

    ``jump=False``: s = t at every step (the flow-matching teacher; with one step, the naive baseline).
    ``jump=True``: s = the next grid time, the average-velocity jumps SnapFlow trains for.
    """

    num_steps: int
    jump: bool

    def __post_init__(self) -> None:
        if self.num_steps < 1:
            raise ValueError(f"num_steps must be at least 1, got {self.num_steps}")

    @property
    def name(self) -> str:
        """Canonical name, accepted back by :meth:`parse`."""
        if self.jump:
            return f"snapflow-{self.num_steps}"
        return "naive-1" if self.num_steps == 1 else f"teacher-{self.num_steps}"

    @classmethod
    def parse(cls, name: str) -> SamplingMode:
        """Read ``teacher-N``, ``snapflow-N``, ``naive`` / ``naive-1`` (bare ``teacher`` = 10, ``snapflow`` = 1)."""
        match = re.fullmatch(r"(teacher|snapflow|naive)(?:-(\d+))?", name.strip().lower())
        if match is None:
            raise ValueError(
                f"unknown sampling mode {name!r}; use teacher-N, snapflow-N or naive (e.g. teacher-10, snapflow-1)"
            )
        kind, steps = match.group(1), match.group(2)
        if kind == "naive":
            if steps not in (None, "1"):
                raise ValueError(f"naive sampling is one step by definition, got {name!r}")
            return cls(1, jump=False)
        if steps is not None and int(steps) < 1:
            raise ValueError(f"sampling mode {name!r} takes no step; a mode needs at least one")
        default_steps = 10 if kind == "teacher" else 1
        return cls(int(steps) if steps else default_steps, jump=kind == "snapflow")


TEACHER_10 = SamplingMode(10, jump=False)
NAIVE_1 = SamplingMode(1, jump=False)
SNAPFLOW_1 = SamplingMode(1, jump=True)


def euler_sample(velocity: VelocityFn, noise: Tensor, mode: SamplingMode) -> Tensor:
    """Integrate from x_1 = ``noise`` at t = 1 to t = 0 with ``mode.num_steps`` Euler steps."""
    # one (steps + 1, B) grid of times; each step reads two rows of it (views, no new tensors per step)
    grid = torch.linspace(1.0, 0.0, mode.num_steps + 1, device=noise.device, dtype=torch.float32)[:, None].expand(
        -1, noise.shape[0]
    )
    x = noise
    for step in range(mode.num_steps):
        t, t_to = grid[step], grid[step + 1]
        x = euler_step(x, velocity(x, t, t_to if mode.jump else t), t, t_to)
    return x


@torch.no_grad()
def sample_actions(policy: FlowPolicy, observation: Any, noise: Tensor, mode: SamplingMode) -> Tensor:
    """Encode ``observation`` once, then denoise ``noise`` into an action chunk with ``mode``."""
    context = policy.encode(observation)
    return euler_sample(lambda x, t, s: policy.velocity(x, t, s, context), noise, mode)


__all__ = ["SamplingMode", "TEACHER_10", "NAIVE_1", "SNAPFLOW_1", "VelocityFn", "euler_sample", "sample_actions"]
