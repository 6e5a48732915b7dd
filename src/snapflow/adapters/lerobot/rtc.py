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
above 1 (LeRobot's default, 10) the jump inpaints at 1 and says so in a warning, never silently.

LeRobot's ``trained`` mode (``RTCConfig.mode``, its training-time RTC) runs for a student distilled with the prefix
given (``distill.rtc_max_delay`` > 0, LeRobot's ``rtc_training_max_delay``): the previous chunk's
first ``inference_delay`` actions ride clean at time 0 through every pass (:func:`snapflow.flow.known_prefix.
sample_continuing`), so the jump itself continues them, and its actions past the delay blend into the previous
chunk's along the schedule's ramp as an untrained jump's do (``prefix_attention_schedule=ZEROS``: no ramp, LeRobot's
trained mode as it is); a policy trained without is refused by name.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import torch
from torch import Tensor

from snapflow.errors import InvalidInputError
from snapflow.flow.known_prefix import sample_continuing
from snapflow.flow.modes import SamplingMode
from snapflow.flow.realtime import inpaint, padded_previous
from snapflow.flow.solver import euler_sample

VelocityFn = Callable[[Tensor, Tensor, Tensor], Tensor]


def rtc_processor_in_force(model: Any) -> Any:
    """The model's ``RTCProcessor`` when its config enables RTC (LeRobot's ``_rtc_enabled``), else None."""
    processor = getattr(model, "rtc_processor", None)
    config = getattr(model.config, "rtc_config", None)
    if processor is None or config is None or not config.enabled:
        return None
    mode = rtc_mode(processor)
    if mode == "trained" and trained_max_delay(model) <= 0:
        raise InvalidInputError(
            "RTC mode 'trained' needs a policy trained with the previous chunk's prefix given: distil its student with "
            "rtc_max_delay > 0 (--policy.distill.rtc_max_delay); this one runs guided RTC (mode 'guided') only"
        )
    if mode not in ("guided", "trained"):
        raise InvalidInputError(f"unknown RTC mode {mode!r}: 'guided' or 'trained'")
    return processor


def rtc_mode(processor: Any) -> str:
    """The processor's RTC mode, ``guided`` where its LeRobot has no other (before its training-time RTC)."""
    mode = getattr(processor.rtc_config, "mode", "guided")
    return str(getattr(mode, "value", mode))


def trained_max_delay(model: Any) -> int:
    """The largest prefix ``model`` was trained to be given (0: none): a student's ``distill.rtc_max_delay``, else
    its config's ``rtc_training_max_delay`` (LeRobot's own field, where its LeRobot has training-time RTC)."""
    settings = getattr(model.config, "distill", None)
    if settings is not None:
        return settings.rtc_max_delay
    return int(getattr(model.config, "rtc_training_max_delay", 0) or 0)


@dataclass(frozen=True)
class TrainedPrefix:
    """What ``trained`` RTC samples with: a :class:`~snapflow.protocol.PerActionTimes` policy, its encoded
    observations and the largest delay it was trained for."""

    policy: Any
    context: Any
    max_delay: int

    def sample(self, noise: Tensor, mode: SamplingMode, prev_chunk_left_over: Tensor, inference_delay: int) -> Tensor:
        """The chunk continuing the leftover's first ``inference_delay`` actions, sampled with ``mode``."""
        if inference_delay > self.max_delay:
            raise InvalidInputError(
                f"an inference delay of {inference_delay} is past the {self.max_delay} actions this policy was trained "
                "to be given; distil it with a larger rtc_max_delay"
            )
        previous = prev_chunk_left_over if prev_chunk_left_over.ndim == 3 else prev_chunk_left_over[None]
        previous = previous.expand(noise.shape[0], -1, -1) if previous.shape[0] == 1 else previous
        return sample_continuing(self.policy, self.context, noise, mode, previous, inference_delay)


def padded_prefix(prev_chunk_left_over: Tensor, like: Tensor) -> Tensor:
    """The previous chunk's leftover, batched and zero-padded to the chunk's shape, as LeRobot pads it."""
    prev = prev_chunk_left_over if prev_chunk_left_over.ndim == 3 else prev_chunk_left_over[None]
    return padded_previous(prev, like)


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
    return inpaint(actions, prev, weights.to(actions), guidance_weight)


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
    trained: TrainedPrefix | None = None,
) -> Tensor:
    """Sample a chunk with ``mode``, continuing ``prev_chunk_left_over`` when RTC is in force (``processor``) and a
    previous chunk is given: in LeRobot's ``trained`` mode the prefix given to every pass (``trained``), else guided
    Euler steps for the teacher's modes; a jump's chunk is then inpainted along the schedule's prefix weights (after
    the delay, given or inpainted, a ramp down to the execution horizon; none under LeRobot's ``ZEROS`` schedule)."""
    if processor is None or prev_chunk_left_over is None:
        return euler_sample(velocity, noise, mode)
    if inference_delay is None:
        raise InvalidInputError("real-time chunking with a previous chunk needs inference_delay")
    if rtc_mode(processor) == "trained":
        if trained is None:
            raise ValueError("trained RTC is in force but no trained prefix sampler was given")
        actions = trained.sample(noise, mode, prev_chunk_left_over, inference_delay)
        if not mode.jump:  # LeRobot's trained mode: the prefix given, nothing steered
            return actions
    elif not mode.jump:
        return guided_euler(velocity, noise, mode, processor, prev_chunk_left_over, inference_delay, execution_horizon)
    else:
        actions = euler_sample(velocity, noise, mode)
    weight = jump_guidance_weight(processor)  # a jump's actions past the delay blend along the schedule's ramp
    return inpaint_prefix(actions, processor, prev_chunk_left_over, inference_delay, execution_horizon, weight)


__all__ = [
    "TrainedPrefix",
    "guided_euler",
    "inpaint_prefix",
    "jump_guidance_weight",
    "padded_prefix",
    "prefix_weights",
    "rtc_mode",
    "rtc_processor_in_force",
    "sample_with_rtc",
    "trained_max_delay",
]
