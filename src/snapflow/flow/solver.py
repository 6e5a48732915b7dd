"""Euler sampling from t = 1 (noise) to t = 0 (actions), for any number of function evaluations.

One network serves every mode: the N-step teacher asks for the instantaneous velocity at each step
(s = t); SnapFlow asks for the average velocity of each jump (s = the next grid time), so SnapFlow 1-NFE
is a single jump from t = 1 to s = 0. Naive 1-NFE is the teacher run with one step (s = t = 1).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import torch
from torch import Tensor

from snapflow.errors import InvalidInputError
from snapflow.flow.modes import SNAPFLOW_1, SamplingMode
from snapflow.flow.path import euler_step
from snapflow.protocol import FlowPolicy, FusedOneStep

VelocityFn = Callable[[Tensor, Tensor, Tensor], Tensor]
"""``velocity(x_t, t, s)`` with the context already bound."""


def euler_sample(velocity: VelocityFn, noise: Tensor, mode: SamplingMode) -> Tensor:
    """Integrate from x_1 = ``noise`` at t = 1 to t = 0 with ``mode.num_steps`` Euler steps."""
    if not mode.resolved:
        raise InvalidInputError(
            "the bare 'teacher' mode samples at a policy's own number of steps: name them (teacher-N), or let the "
            "opened policy resolve it (OpenedPolicy.resolve_mode)"
        )
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
    """Encode ``observation`` once, then denoise ``noise`` into an action chunk with ``mode``. SnapFlow 1-NFE runs
    the policy's ``one_step_chunk(observation, noise)`` where a fast path fused the prefix and the jump into one
    graph (:func:`snapflow.inference.compile.fuse_one_step`).

    Args:
        policy: any :class:`~snapflow.protocol.FlowPolicy`.
        observation: one batch of what the policy's ``encode`` reads.
        noise: the starting point x_1, shaped as the action chunks (B, chunk length, action width).
        mode: how many Euler steps, each with or without the jump (:meth:`SamplingMode.parse`).

    Returns:
        The action chunks, shaped as ``noise``.

    Examples:
        >>> import torch
        >>> from snapflow import SamplingMode, SnapFlowPolicy, sample_actions
        >>> from snapflow.policies.mlp import MLPFlowModel, MLPPolicyConfig
        >>> config = MLPPolicyConfig(
        ...     observation_dim=4, action_dim=2, chunk_length=3, hidden_dim=32
        ... )
        >>> policy = SnapFlowPolicy(MLPFlowModel(config))
        >>> observation, noise = torch.randn(5, 4), torch.randn(5, 3, 2)
        >>> with torch.no_grad():
        ...     mode = SamplingMode.parse("teacher-10")
        ...     chunk = sample_actions(policy, observation, noise, mode)
        >>> chunk.shape
        torch.Size([5, 3, 2])
    """
    if isinstance(policy, FusedOneStep) and mode == SNAPFLOW_1:
        return policy.one_step_chunk(observation, noise)
    context = policy.encode(observation)
    return euler_sample(lambda x, t, s: policy.velocity(x, t, s, context), noise, mode)


__all__ = ["VelocityFn", "euler_sample", "sample_actions"]
