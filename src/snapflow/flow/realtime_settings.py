"""How chunks continue each other under an inference delay (:mod:`snapflow.flow.realtime` samples them): plain
Python, read by the CLI before torch loads."""

from __future__ import annotations

from dataclasses import asdict, dataclass, replace
from typing import Any

from snapflow.errors import InvalidInputError
from snapflow.flow.modes import SamplingMode

RTC_KINDS = ("auto", "guided", "inpaint", "trained")
PREFIX_SCHEDULES = ("linear", "zeros")


@dataclass(frozen=True)
class RealTimeChunking:
    """How chunks continue each other under an inference delay.

    Args:
        delay: actions executed while a chunk is computed (the new chunk's first ones are the previous chunk's).
        kind: ``guided``, ``inpaint`` or ``trained`` (:mod:`snapflow.flow.realtime`), or ``auto``: each mode's
            own, ``guided`` for Euler modes (teacher-N, naive) and ``inpaint`` for jumps (snapflow-N), as the LeRobot
            adapter's guided RTC samples them.
        execution_horizon: where the weights' ramp reaches 0 (at most the previous chunk's leftover); None: the
            whole leftover.
        schedule: ``linear`` (LeRobot's default ramp) or ``zeros`` (no ramp: weight 1 over the delay only).
        max_guidance_weight: the guided step's largest weight (LeRobot's default 10).
        jump_weight: the weight a jump's chunk is inpainted at, in [0, 1].
    """

    delay: int
    kind: str = "auto"
    execution_horizon: int | None = None
    schedule: str = "linear"
    max_guidance_weight: float = 10.0
    jump_weight: float = 1.0

    def __post_init__(self) -> None:
        if isinstance(self.delay, bool) or not isinstance(self.delay, int) or self.delay < 0:
            raise InvalidInputError(f"an inference delay is a whole number of actions, 0 or more, got {self.delay!r}")
        if self.kind not in RTC_KINDS:
            raise InvalidInputError(f"unknown real-time chunking kind {self.kind!r}: one of {', '.join(RTC_KINDS)}")
        if self.schedule not in PREFIX_SCHEDULES:
            raise InvalidInputError(f"unknown prefix schedule {self.schedule!r}: one of {', '.join(PREFIX_SCHEDULES)}")
        horizon = self.execution_horizon
        if horizon is not None and (isinstance(horizon, bool) or not isinstance(horizon, int) or horizon < 1):
            raise InvalidInputError(f"an execution horizon is a whole number of actions, 1 or more, got {horizon!r}")
        if not self.max_guidance_weight > 0:
            raise InvalidInputError(f"max_guidance_weight must be positive, got {self.max_guidance_weight}")
        if not 0 <= self.jump_weight <= 1:
            raise InvalidInputError(f"a jump's inpainting weight is between 0 and 1, got {self.jump_weight}")

    def for_mode(self, mode: SamplingMode) -> RealTimeChunking:
        """This setting for ``mode``: ``auto`` resolved, guidance of a jump refused (:meth:`check_mode`)."""
        if self.kind == "auto":
            return replace(self, kind="inpaint" if mode.jump else "guided")
        self.check_mode(mode)
        return self

    def check_mode(self, mode: SamplingMode) -> None:
        """Refuse guidance for a jump, which integrates nothing to steer (its kind is ``inpaint``)."""
        if self.kind == "guided" and mode.jump:
            raise InvalidInputError(
                f"guided real-time chunking steers Euler steps; {mode.name} jumps: inpaint its chunk (kind 'inpaint') "
                "or give it known prefixes (kind 'trained')"
            )

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


__all__ = ["PREFIX_SCHEDULES", "RTC_KINDS", "RealTimeChunking"]
