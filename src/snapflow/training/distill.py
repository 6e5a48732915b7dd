"""Settings of a distillation run, shared by every policy family."""

from __future__ import annotations

from dataclasses import dataclass, replace

from snapflow.flow.time_sampling import BetaTimeSampler, TimeSampler
from snapflow.objective import (
    BootstrappedSnapFlowObjective,
    ConsistencyDistillationObjective,
    MeanFlowObjective,
    SnapFlowObjective,
    TwoBranchObjective,
)
from snapflow.objective.snapflow import TEACHER_VELOCITIES, target_stages

METHODS = ("snapflow", "consistency-distillation", "meanflow")
TARGETS = ("euler", "bootstrap")


@dataclass(frozen=True)
class DistillSettings:
    """The paper's defaults: SnapFlow, alpha 0.5, lambda 0.1, no clamp, prefix (VLM) frozen, phi_s attached,
    two-step Euler target.

    ``method`` picks the one-step objective (the baselines share alpha and lambda); ``teacher_velocity``
    and ``target_time`` exist for the paper's ablations (conditional velocity; no target-time embedding).
    SnapFlow's target is ``target="euler"`` (the average of ``target_steps`` Euler velocities; a list of
    them is a schedule over equal stages of training) or ``target="bootstrap"`` (built from the model's own
    half-jumps, reaching ``target_steps`` Euler steps at three passes per row; see
    :mod:`snapflow.objective.bootstrap`).
    """

    alpha: float = 0.5
    consistency_weight: float = 0.1
    teacher_velocity_clamp: float | None = None
    freeze_prefix: bool = True
    method: str = "snapflow"
    teacher_velocity: str = "marginal"
    target_time: bool = True
    target: str = "euler"
    target_steps: int | tuple[int, ...] = 2

    def __post_init__(self) -> None:
        if isinstance(self.target_steps, list):  # as read from TOML or JSON
            object.__setattr__(self, "target_steps", tuple(self.target_steps))
        if self.target not in TARGETS:
            raise ValueError(f"unknown SnapFlow target {self.target!r}; choose one of {list(TARGETS)}")
        if self.method not in METHODS:
            raise ValueError(f"unknown distillation method {self.method!r}; choose one of {list(METHODS)}")
        if self.teacher_velocity not in TEACHER_VELOCITIES:
            raise ValueError(f"teacher_velocity must be one of {list(TEACHER_VELOCITIES)}, got {self.teacher_velocity!r}")
        if self.method != "snapflow" and (self.teacher_velocity != "marginal" or self.teacher_velocity_clamp is not None):
            raise ValueError("teacher_velocity and the velocity clamp are options of the snapflow method only")
        if self.method != "snapflow" and (self.target != "euler" or self.target_steps != 2):
            raise ValueError("target and target_steps are options of the snapflow method only")
        if self.target == "bootstrap" and (self.teacher_velocity != "marginal" or self.teacher_velocity_clamp is not None):
            raise ValueError("the bootstrapped target is built from the model's own jumps: it takes no teacher_velocity or clamp")
        if self.target == "bootstrap" and not isinstance(self.target_steps, int):
            raise ValueError(f"a bootstrapped target grows by itself; give target_steps one power of two, not the schedule {list(self.target_steps)}")
        self.objective(BetaTimeSampler())  # the objective checks its own settings (target_steps) with named errors

    def objective(self, time_sampler: TimeSampler) -> TwoBranchObjective:
        """The chosen loss with these settings and the policy's own FM time distribution."""
        if self.method == "consistency-distillation":
            return ConsistencyDistillationObjective(self.alpha, self.consistency_weight, time_sampler)
        if self.method == "meanflow":
            return MeanFlowObjective(self.alpha, self.consistency_weight, time_sampler)
        if self.target == "bootstrap":
            return BootstrappedSnapFlowObjective(self.alpha, self.consistency_weight, time_sampler, self.target_steps)
        return SnapFlowObjective(self.alpha, self.consistency_weight, time_sampler, self.teacher_velocity_clamp, self.teacher_velocity,
                                 self.target_steps)


def parse_target_steps(text: str) -> int | tuple[int, ...]:
    """``8``, or a schedule ``2,4,8``."""
    try:
        steps = tuple(int(k) for k in text.split(","))
    except ValueError:
        raise ValueError(f"target steps must be integers (8, or a schedule such as 2,4,8), got {text!r}") from None
    return steps[0] if len(steps) == 1 else steps


@dataclass(frozen=True)
class TargetOption:
    """A SnapFlow target and its Euler steps (a tuple: a schedule over equal stages of training)."""

    target: str
    steps: int | tuple[int, ...]

    @classmethod
    def parse(cls, text: str) -> TargetOption:
        """``euler:8``, ``euler:2,4,8`` (a schedule) or ``bootstrap:8``."""
        target, _, steps = text.partition(":")
        if target not in TARGETS or not steps:
            raise ValueError(f"a target option reads TARGET:STEPS with TARGET in {list(TARGETS)}, e.g. euler:8, euler:2,4,8 or bootstrap:8; got {text!r}")
        return cls(target, parse_target_steps(steps))

    @property
    def name(self) -> str:
        steps = self.steps if isinstance(self.steps, int) else "-".join(map(str, self.steps))
        return f"{self.target}-{steps}"

    @property
    def label(self) -> str:
        if self.target == "bootstrap":
            return f"bootstrapped (K -> {self.steps})"
        return f"K = {self.steps}" if isinstance(self.steps, int) else "K = " + " -> ".join(map(str, self.steps))

    def settings(self, base: DistillSettings | None = None) -> DistillSettings:
        """``base`` (default: the paper's settings) with this target."""
        return replace(base or DistillSettings(), target=self.target, target_steps=self.steps)

    @property
    def teacher_passes(self) -> float:
        """No-grad passes per one-step row (averaged over a schedule's stages); each row adds one gradient pass."""
        if self.target == "bootstrap":
            return 2.0
        stages = target_stages(self.steps)
        return sum(stages) / len(stages)


__all__ = ["DistillSettings", "METHODS", "TARGETS", "TargetOption", "parse_target_steps"]
