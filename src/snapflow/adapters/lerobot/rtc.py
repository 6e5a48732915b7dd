"""Real-time chunking (RTC) for a LeRobot policy under any sampling mode.

LeRobot's guided RTC steers each Euler step toward the previous chunk's unexecuted prefix:
``v <- v - w(t) * J^T [(prev - x0_hat) * weights]`` with ``x0_hat = x_t - t * v``, the weight ``w(t)`` growing to
``max_guidance_weight`` (10 by default) at t = 1. (LeRobot's ``RTCProcessor.denoise_step`` evaluates v before x_t
requires grad, so its J is the identity: the correction is ``(prev - x0_hat) * weights``.) Over N steps each
correction is scaled by dt = 1/N, so the pull toward the prefix is integrated gently. ``teacher-N`` keeps exactly
that (:func:`guided_euler`, LeRobot's own ``denoise_step`` at every step).

One jump integrates nothing: LeRobot's guided jump from t = 1 is ``a + w * (prev - a) * weights`` with w = 10, which
lands nine times the gap past the prefix on its other side. What carries over is the same correction at w = 1:
inpainting of the prefix with LeRobot's prefix weights (:func:`inpaint_prefix`): the actions executed while the chunk
is computed are the previous chunk's, the next ones blend into the new chunk along the weights' ramp, and the rest
is the jump's own. No backward pass. ``max_guidance_weight`` acts up to 1 (0.5: half the pull toward the prefix);
above 1 (LeRobot's default, 10) the jump inpaints at 1 and says so in a warning, never silently. LeRobot's trained
RTC (the prefix given in training) is refused by name: no student here was distilled with the prefix given.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable
from typing import Any

import torch
from torch import Tensor

from snapflow.errors import InvalidInputError
from snapflow.flow.modes import SamplingMode
from snapflow.flow.solver import euler_sample

VelocityFn = Callable[[Tensor, Tensor, Tensor], Tensor]


def rtc_processor_in_force(model: Any) -> Any:
    """The model's ``RTCProcessor`` when its config enables RTC (LeRobot's ``_rtc_enabled``), else None."""
    processor = getattr(model, "rtc_processor", None)
    config = getattr(model.config, "rtc_config", None)
    if processor is None or config is None or not config.enabled:
        return None
    mode = getattr(config, "mode", "guided")
    if str(getattr(mode, "value", mode)) != "guided":
        raise InvalidInputError(
            f"RTC mode {mode!r} needs a policy trained with the previous chunk's prefix given; snapflow's students "
            "run guided RTC (teacher-N) and prefix inpainting (snapflow-N) only"
        )
    return processor


def padded_prefix(prev_chunk_left_over: Tensor, like: Tensor) -> Tensor:
    """The previous chunk's leftover, batched and zero-padded to the chunk's shape, as LeRobot pads it."""
    prev = prev_chunk_left_over if prev_chunk_left_over.ndim == 3 else prev_chunk_left_over[None]
    padded = like.new_zeros(like.shape)
    steps, dims = min(prev.shape[1], like.shape[1]), min(prev.shape[2], like.shape[2])
    padded[:, :steps, :dims] = prev[:, :steps, :dims].to(like)
    return padded


def prefix_weights(processor: Any, prev: Tensor, inference_delay: int, horizon: int | None, chunk: int) -> Tensor:
    """LeRobot's prefix weights (1 over the ``inference_delay`` actions executed while the chunk is computed, then
    its schedule down to 0 at the execution horizon), shaped (1, chunk, 1)."""
    horizon = processor.rtc_config.execution_horizon if horizon is None else horizon
    horizon = min(horizon, prev.shape[-2])  # as LeRobot: a short leftover shortens the horizon
    return processor.get_prefix_weights(inference_delay, horizon, chunk)[None, :, None]


def guided_euler(
    velocity: VelocityFn,
    noise: Tensor,
    mode: SamplingMode,
    processor: Any,
    prev_chunk_left_over: Tensor,
    inference_delay: int,
    execution_horizon: int | None,
) -> Tensor:
    """``mode.num_steps`` Euler steps of the instantaneous velocity (s = t), each through LeRobot's guided RTC
    (``RTCProcessor.denoise_step``), as LeRobot's own sampler runs them."""
    x, dt = noise, -1.0 / mode.num_steps
    for step in range(mode.num_steps):
        time = 1.0 + step * dt  # LeRobot's grid, to the last bit
        t = torch.tensor(time, dtype=torch.float32, device=noise.device).expand(noise.shape[0])
        v = processor.denoise_step(
            x_t=x,
            prev_chunk_left_over=prev_chunk_left_over,
            inference_delay=inference_delay,
            time=time,
            original_denoise_step_partial=lambda x_t, t=t: velocity(x_t, t, t),
            execution_horizon=execution_horizon,
        )
        x = x + dt * v
    return x


def inpaint_prefix(
    actions: Tensor,
    processor: Any,
    prev_chunk_left_over: Tensor,
    inference_delay: int,
    execution_horizon: int | None,
    guidance_weight: float = 1.0,
) -> Tensor:
    """The chunk with the previous chunk's prefix inpainted: ``a + w * weights * (prev - a)``, the guided correction
    at weight ``w`` = ``guidance_weight`` (at most 1, see the module's docstring)."""
    if not 0 <= guidance_weight <= 1:
        raise InvalidInputError(f"a jump's guidance weight is between 0 and 1, got {guidance_weight}")
    prev = padded_prefix(prev_chunk_left_over, actions)
    weights = prefix_weights(processor, prev_chunk_left_over, inference_delay, execution_horizon, actions.shape[1])
    return actions + guidance_weight * weights.to(actions) * (prev - actions)


def jump_guidance_weight(processor: Any) -> float:
    """The guidance weight a jump applies: the processor's ``max_guidance_weight`` up to 1; above it, 1, with a
    warning that says why (Python shows it once a place, as every warning)."""
    asked = float(processor.rtc_config.max_guidance_weight)
    if asked > 1:
        warnings.warn(
            f"guided RTC's max_guidance_weight {asked:g} would throw a one-step jump {asked - 1:g} times the gap past "
            "the previous chunk's prefix: the jump inpaints the prefix at weight 1 (teacher-N modes apply "
            f"{asked:g} per Euler step); give max_guidance_weight <= 1 to pull less",
            stacklevel=3,
        )
    return min(asked, 1.0)


def sample_with_rtc(
    velocity: VelocityFn,
    noise: Tensor,
    mode: SamplingMode,
    processor: Any,
    prev_chunk_left_over: Tensor | None,
    inference_delay: int | None,
    execution_horizon: int | None,
) -> Tensor:
    """Sample a chunk with ``mode``, continuing ``prev_chunk_left_over`` when RTC is in force (``processor``) and a
    previous chunk is given: guided Euler steps for the teacher's modes, prefix inpainting for jumps."""
    if processor is None or prev_chunk_left_over is None:
        return euler_sample(velocity, noise, mode)
    if inference_delay is None:
        raise InvalidInputError("real-time chunking with a previous chunk needs inference_delay")
    if not mode.jump:
        return guided_euler(velocity, noise, mode, processor, prev_chunk_left_over, inference_delay, execution_horizon)
    actions = euler_sample(velocity, noise, mode)
    weight = jump_guidance_weight(processor)
    return inpaint_prefix(actions, processor, prev_chunk_left_over, inference_delay, execution_horizon, weight)


__all__ = [
    "guided_euler",
    "inpaint_prefix",
    "jump_guidance_weight",
    "padded_prefix",
    "prefix_weights",
    "rtc_processor_in_force",
    "sample_with_rtc",
]
