"""Real-time chunking (RTC) for any :class:`~snapflow.protocol.FlowPolicy`, in plain torch: LeRobot's prefix weights
and guided Euler step without LeRobot (an optional extra), and one sampler of a chunk that continues a previous one.

While a robot computes its next chunk it keeps executing the previous one: the new chunk's first ``delay`` actions
are already decided, and the ones after should join the previous chunk's smoothly. Three ways, one per kind:

* ``guided`` (teacher-N modes): each Euler step steered toward the previous chunk's leftover,
  ``v <- v - w(t) * (prev - x0_hat) * weights`` with ``x0_hat = x_t - t * v``, as LeRobot's
  ``RTCProcessor.denoise_step`` computes it (v evaluated before x_t requires grad, so its Jacobian is the identity),
  ``w(t)`` growing to ``max_guidance_weight`` at t = 1 (:func:`guidance_weight`). A jump integrates nothing, so a jump
  mode is refused here: its kind is ``inpaint``.
* ``inpaint`` (jumps): the sampled chunk blended into the previous one along the weights, ``a + w * weights *
  (prev - a)`` with ``w = jump_weight`` <= 1 (LeRobot's guided correction at weight w, which the LeRobot adapter's
  jumps apply: :mod:`snapflow.adapters.lerobot.rtc`).
* ``trained``: a policy distilled with known prefixes (``DistillSettings.rtc_max_delay``) given the previous chunk's
  first ``delay`` actions at time 0 in every pass (:func:`snapflow.flow.known_prefix.sample_continuing`); a jump's
  actions past the delay then blend along the ramp as ``inpaint``'s do.

The weights (:func:`prefix_weights`, LeRobot's ``get_prefix_weights``) are 1 over the delay, then (``linear``
schedule) fall linearly to 0 at the execution horizon, or (``zeros``) drop to 0 at once. The execution horizon is
where the ramp ends, at most the previous chunk's leftover; by default all of it (Kinetix's H - s in steady state).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import torch
from torch import Tensor

from snapflow.errors import InvalidInputError
from snapflow.flow.known_prefix import sample_continuing
from snapflow.flow.modes import SamplingMode
from snapflow.flow.realtime_settings import PREFIX_SCHEDULES, RTC_KINDS, RealTimeChunking
from snapflow.flow.solver import euler_sample
from snapflow.protocol import Context

VelocityFn = Callable[[Tensor, Tensor, Tensor], Tensor]


def prefix_weights(delay: int, execution_horizon: int, chunk_length: int, schedule: str = "linear") -> Tensor:
    """(chunk_length,) weights: 1 over the first ``delay`` actions, then (``linear``) down to 0 at
    ``execution_horizon`` or (``zeros``) 0 at once; LeRobot's ``RTCProcessor.get_prefix_weights``, to the bit."""
    start = min(delay, execution_horizon)
    if schedule == "zeros":
        weights = torch.zeros(chunk_length)
        weights[:start] = 1.0
        return weights
    if schedule != "linear":
        raise InvalidInputError(f"unknown prefix schedule {schedule!r}: one of {', '.join(PREFIX_SCHEDULES)}")
    steps = chunk_length - max(chunk_length - execution_horizon, 0) - start
    ramp = torch.tensor([]) if execution_horizon <= start or steps <= 0 else torch.linspace(1, 0, steps + 2)[1:-1]
    if chunk_length - execution_horizon > 0:
        ramp = torch.cat([ramp, torch.zeros(chunk_length - execution_horizon)])
    if min(start, chunk_length) > 0:
        ramp = torch.cat([torch.ones(min(start, chunk_length)), ramp])
    return ramp


def guidance_weight(time: float, max_guidance_weight: float) -> Tensor:
    """The guided step's weight at flow time ``time`` (1: noise): LeRobot's schedule, clipped at the maximum."""
    maximum, tau = torch.as_tensor(max_guidance_weight), torch.as_tensor(1 - time)
    squared_one_minus_tau = (1 - tau) ** 2
    inv_r2 = (squared_one_minus_tau + tau**2) / squared_one_minus_tau
    c = torch.nan_to_num((1 - tau) / tau, posinf=maximum)
    return torch.minimum(torch.nan_to_num(c * inv_r2, posinf=maximum), maximum)


def padded_previous(previous: Tensor, like: Tensor) -> Tensor:
    """The previous chunk's leftover (B, P, width) zero-padded (or cut) to ``like``'s (B, chunk, width)."""
    padded = like.new_zeros(like.shape)
    steps, width = min(previous.shape[1], like.shape[1]), min(previous.shape[2], like.shape[2])
    padded[:, :steps, :width] = previous[:, :steps, :width].to(like)
    return padded


def continuation_weights(rtc: RealTimeChunking, previous: Tensor, like: Tensor) -> Tensor:
    """(1, chunk, 1) prefix weights for a leftover ``previous`` (B, P, width): the horizon at most P, as LeRobot."""
    horizon = previous.shape[1] if rtc.execution_horizon is None else min(rtc.execution_horizon, previous.shape[1])
    return prefix_weights(rtc.delay, horizon, like.shape[1], rtc.schedule).to(like)[None, :, None]


def guided_euler(
    velocity: VelocityFn, noise: Tensor, num_steps: int, previous: Tensor, weights: Tensor, max_guidance_weight: float
) -> Tensor:
    """``num_steps`` Euler steps of the instantaneous velocity (s = t), each steered toward ``previous`` (padded to
    the chunk's shape) by ``weights`` (1, chunk, 1), as LeRobot's guided RTC steps (its grid, to the last bit)."""
    x, dt = noise, -1.0 / num_steps
    for step in range(num_steps):
        time = 1.0 + step * dt
        t = torch.tensor(time, dtype=torch.float32, device=noise.device).expand(noise.shape[0])
        v = velocity(x, t, t)
        correction = (previous - (x - time * v)) * weights
        x = x + dt * (v - guidance_weight(time, max_guidance_weight) * correction)
    return x


def inpaint(actions: Tensor, previous: Tensor, weights: Tensor, weight: float = 1.0) -> Tensor:
    """``actions + weight * weights * (previous - actions)``: the chunk blended into the previous one's leftover."""
    return actions + weight * weights * (previous - actions)


@torch.no_grad()
def sample_chunk_continuing(
    policy: Any, context: Context, noise: Tensor, mode: SamplingMode, previous: Tensor, rtc: RealTimeChunking
) -> Tensor:
    """A chunk sampled with ``mode`` that continues ``previous`` under ``rtc``.

    Args:
        policy: a :class:`~snapflow.protocol.FlowPolicy` (a :class:`~snapflow.protocol.PerActionTimes` one for
            ``trained``); ``context``: its encoded observations.
        noise: (B, chunk, width), where the chunk starts.
        previous: (B, P, width), the previous chunk's actions from the one executed next, P >= ``rtc.delay``.
        mode: a resolved mode (``teacher-N``, ``naive``, ``snapflow-N``).
        rtc: the setting; its kind ``auto`` is ``guided`` for Euler modes and ``inpaint`` for jumps.
    """
    rtc = rtc.for_mode(mode)
    if not mode.resolved:
        raise ValueError(f"{mode.name} must be resolved to its number of steps before it samples")
    if previous.shape[1] < rtc.delay:
        raise InvalidInputError(
            f"an inference delay of {rtc.delay} needs that many actions left of the previous chunk, got "
            f"{previous.shape[1]}"
        )
    weights, padded = continuation_weights(rtc, previous, noise), padded_previous(previous, noise)

    def velocity(x: Tensor, t: Tensor, s: Tensor) -> Tensor:
        return policy.velocity(x, t, s, context)

    if rtc.kind == "guided":
        return guided_euler(velocity, noise, mode.num_steps, padded, weights, rtc.max_guidance_weight)
    if rtc.kind == "trained":
        actions = sample_continuing(policy, context, noise, mode, previous, rtc.delay)
        if not mode.jump:  # the prefix given to every step, nothing steered (LeRobot's trained mode)
            return actions
    else:
        actions = euler_sample(velocity, noise, mode)
    return inpaint(actions, padded, weights, rtc.jump_weight)


__all__ = [
    "PREFIX_SCHEDULES",
    "RTC_KINDS",
    "RealTimeChunking",
    "continuation_weights",
    "guidance_weight",
    "guided_euler",
    "inpaint",
    "padded_previous",
    "prefix_weights",
    "sample_chunk_continuing",
]
