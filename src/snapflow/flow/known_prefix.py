"""A chunk whose first actions are known: real-time chunking trained in (LeRobot's training-time RTC).

While a robot computes its next chunk it keeps executing the previous one, so the new chunk's first ``d`` actions
(the inference delay) are already decided. Training-time RTC (arXiv 2512.05964; LeRobot's
``rtc_training_max_delay``) gives the model those actions as they are: clean, at flow time 0, beside the others at
the row's time, and the loss leaves them out. A model trained so continues a given prefix in one pass, where
guidance (:mod:`snapflow.adapters.lerobot.rtc`) needs a backward pass a step or, for a jump, inpaints after the fact.

:class:`KnownPrefixPolicy` is that conditioning as a view of any :class:`~snapflow.protocol.PerActionTimes` policy,
speaking :class:`~snapflow.protocol.FlowPolicy` with per-row times, so that every objective and the Euler solver run
on it unchanged: each velocity pass sees the known actions in place of the chunk's first ones, at time and target
time 0, and answers velocity 0 there (a known action does not move), so an Euler step or a jump keeps the prefix
where it started. The known actions and their mask ride in the context, which the objective slices row by row.
"""

from __future__ import annotations

from typing import Any

import torch
from torch import Tensor

from snapflow.errors import InvalidInputError
from snapflow.flow.modes import SamplingMode
from snapflow.flow.solver import euler_sample
from snapflow.protocol import Context, PaddedActions, PerActionTimes, draw_flow_noise


def per_action_times_refusal(policy: Any) -> str | None:
    """None where ``policy`` takes a time per action (:class:`~snapflow.protocol.PerActionTimes`), else why not."""
    if not isinstance(policy, PerActionTimes):
        return f"{type(policy).__name__} takes one time a chunk"
    return getattr(policy, "per_action_times_refusal", None)


def prefix_mask(delays: Tensor, chunk_length: int) -> Tensor:
    """(B, chunk_length) booleans, True on each row's first ``delays[row]`` actions."""
    return torch.arange(chunk_length, device=delays.device)[None, :] < delays[:, None]


def draw_delays(count: int, max_delay: int, generator: torch.Generator | None, device: torch.device) -> Tensor:
    """Each row's number of known actions, uniform on 0..``max_delay`` (as LeRobot's training-time RTC draws it)."""
    return torch.randint(0, max_delay + 1, (count,), generator=generator, device=device)


class KnownPrefixPolicy:
    """``policy`` conditioned on known first actions of its chunks (a :class:`~snapflow.protocol.FlowPolicy`).

    Args:
        policy: a :class:`~snapflow.protocol.PerActionTimes` policy whose chunks are (B, chunk length, width).
        known: (B, chunk length, width) chunks whose masked entries are the known actions (the rest is unread).
        mask: (B, chunk length) booleans, True on the known actions.

    Raises:
        InvalidInputError: ``policy`` takes one time a row only.
    """

    def __init__(self, policy: Any, known: Tensor, mask: Tensor) -> None:
        refusal = per_action_times_refusal(policy)
        if refusal is not None:
            raise InvalidInputError(
                f"{refusal}, so it cannot be given known actions at time 0 (real-time chunking trained in needs a "
                "policy whose time enters each action: SmolVLA's, a built-in transformer's)"
            )
        if known.shape[:2] != mask.shape:
            raise ValueError(f"mask {tuple(mask.shape)} must cover the chunks' first two axes {tuple(known.shape)}")
        self.policy, self.known, self.mask = policy, known, mask

    def encode(self, observation: Any) -> Context:
        """The policy's context, with the known actions and their mask beside it (sliced with its rows)."""
        return {"policy": self.policy.encode(observation), "known": self.known, "mask": self.mask}

    def velocity(self, x_t: Tensor, t: Tensor, s: Tensor, context: Context) -> Tensor:
        """The policy's velocity with the known actions in place at time 0, and 0 on them."""
        mask = context["mask"]
        x_in = with_known(x_t, context["known"], mask)
        zero = torch.zeros((), dtype=t.dtype, device=t.device)
        t_each = torch.where(mask, zero, t[:, None].expand(mask.shape))
        s_each = torch.where(mask, zero, s[:, None].expand(mask.shape))
        velocity = self.policy.velocity_per_action(x_in, t_each, s_each, context["policy"])
        return velocity.masked_fill(mask[..., None], 0.0)

    def action_weights(self, observation: Any) -> Tensor:
        """The policy's own loss weights (:class:`~snapflow.protocol.PaddedActions`) with the known actions left out:
        the loss is the rest of the chunk's."""
        unknown = (~self.mask)[..., None].to(self.known.dtype)
        own = self.policy.action_weights(observation) if isinstance(self.policy, PaddedActions) else None
        return unknown if own is None else own.to(unknown) * unknown

    def flow_noise(self, shape: tuple[int, ...], generator: Any = None, device: Any = None) -> Tensor:
        """The policy's own noise (:class:`~snapflow.protocol.OwnNoise`) or a standard normal."""
        return draw_flow_noise(self.policy, shape, generator, device)


def with_known(x: Tensor, known: Tensor, mask: Tensor) -> Tensor:
    """``x`` with its masked actions replaced by ``known``'s."""
    return torch.where(mask[..., None], known.to(x), x)


@torch.no_grad()
def sample_continuing(
    policy: Any, context: Context, noise: Tensor, mode: SamplingMode, previous: Tensor, delay: int
) -> Tensor:
    """A chunk whose first ``delay`` actions are ``previous``'s (the actions executed while it is computed), the
    rest sampled with ``mode`` by a policy trained with known prefixes: every step conditioned on them (hard
    inpainting, LeRobot's ``trained`` RTC mode), for a jump as for the teacher's Euler steps.

    Args:
        policy: a :class:`~snapflow.protocol.PerActionTimes` policy; ``context``: its encoded observations.
        noise: (B, chunk length, width), where the chunk starts.
        previous: (B, at least ``delay``, width), the previous chunk's actions from the one executed next.
        delay: how many of them are executed before the new chunk arrives.
    """
    if not 0 <= delay < noise.shape[1] or delay > previous.shape[1]:
        raise InvalidInputError(
            f"an inference delay of {delay} needs 0 <= delay < the chunk's {noise.shape[1]} actions and at most the "
            f"{previous.shape[1]} left of the previous chunk"
        )
    known = noise.new_zeros(noise.shape)
    known[:, :delay, : previous.shape[2]] = previous[:, :delay, : noise.shape[2]].to(noise)
    mask = prefix_mask(torch.full((noise.shape[0],), delay, device=noise.device), noise.shape[1])
    view = KnownPrefixPolicy(policy, known, mask)
    conditioned = {"policy": context, "known": known, "mask": mask}
    return euler_sample(lambda x, t, s: view.velocity(x, t, s, conditioned), with_known(noise, known, mask), mode)


__all__ = [
    "KnownPrefixPolicy",
    "draw_delays",
    "per_action_times_refusal",
    "prefix_mask",
    "sample_continuing",
    "with_known",
]
