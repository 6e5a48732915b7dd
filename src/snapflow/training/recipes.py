"""What a student is distilled with: the settings of a distillation run (shared by every policy family) and the named
recipes, each a student's training and distillation settings.

Plain Python at import (the CLI reads these settings before torch loads); the objective is built on demand. The stage
that distils a built-in teacher with them is :func:`snapflow.training.stages.distill`.
"""

from __future__ import annotations

from dataclasses import dataclass, fields, replace
from typing import TYPE_CHECKING, Any, Literal, get_args

from snapflow.objective.options import TeacherVelocity, target_stages
from snapflow.training.config import PAPER_STUDENT_TRAINING, TrainConfig

if TYPE_CHECKING:
    from snapflow.flow.time_sampling import TimeSampler
    from snapflow.objective.base import TwoBranchObjective

Method = Literal["snapflow", "consistency-distillation", "meanflow"]
Target = Literal["euler", "bootstrap"]
METHODS: tuple[str, ...] = get_args(Method)
TARGETS: tuple[str, ...] = get_args(Target)
# the settings that reach the objective as keyword options (alpha and lambda reach every objective)
OBJECTIVE_OPTIONS = ("teacher_velocity_clamp", "teacher_velocity", "target_steps", "intermediate_jumps")


@dataclass(frozen=True)
class DistillSettings:
    """The paper's defaults: SnapFlow, alpha 0.5, lambda 0.1, no clamp, prefix (VLM) frozen, phi_s attached,
    two-step Euler target.

    ``method`` picks the one-step objective (the baselines share alpha and lambda); ``teacher_velocity``
    and ``target_time`` exist for the paper's ablations (conditional velocity; no target-time embedding).
    SnapFlow's target is ``target="euler"`` (the average of ``target_steps`` Euler velocities; a list of
    them is a schedule over equal stages of training) or ``target="bootstrap"`` (built from the model's own
    half-jumps, reaching ``target_steps`` Euler steps at three passes per row; see
    :mod:`snapflow.objective.bootstrap`). ``intermediate_jumps`` is the share of SnapFlow's one-step rows that jump
    between inner times (t, s) instead of 1 -> 0. An option the chosen objective does not take must keep its default.
    """

    alpha: float = 0.5
    consistency_weight: float = 0.1
    teacher_velocity_clamp: float | None = None
    freeze_prefix: bool = True
    method: Method = "snapflow"
    teacher_velocity: TeacherVelocity = "marginal"
    target_time: bool = True
    target: Target = "euler"
    target_steps: int | tuple[int, ...] = 2
    intermediate_jumps: float = 0.0

    def __post_init__(self) -> None:
        if isinstance(self.target_steps, list):  # as read from TOML or JSON
            object.__setattr__(self, "target_steps", tuple(self.target_steps))
        if self.target not in TARGETS:
            raise ValueError(f"unknown SnapFlow target {self.target!r}; choose one of {list(TARGETS)}")
        if self.method not in METHODS:
            raise ValueError(f"unknown distillation method {self.method!r}; choose one of {list(METHODS)}")
        if self.method != "snapflow" and self.target != "euler":
            raise ValueError("target is an option of the snapflow method only")
        from snapflow.flow.time_sampling import BetaTimeSampler

        self.objective(BetaTimeSampler())  # the objective names what it does not take, and checks its own values

    @property
    def objective_name(self) -> str:
        """The registered objective these settings pick (:data:`snapflow.objective.registry.OBJECTIVES`)."""
        return "snapflow-bootstrap" if self.method == "snapflow" and self.target == "bootstrap" else self.method

    def objective(self, time_sampler: TimeSampler) -> TwoBranchObjective:
        """The chosen loss with these settings and the policy's own FM time distribution: every option the objective
        takes is passed; one it does not take must be at its default."""
        from snapflow.objective.registry import make_objective, objective_options

        accepted = objective_options(self.objective_name)
        defaults = {field.name: field.default for field in fields(self)}
        options = {}
        for name in OBJECTIVE_OPTIONS:
            value = getattr(self, name)
            if name in accepted:
                options[name] = value
            elif value != defaults[name]:
                raise ValueError(f"{name} is not an option of the {self.objective_name} objective")
        return make_objective(
            self.objective_name,
            alpha=self.alpha,
            consistency_weight=self.consistency_weight,
            time_sampler=time_sampler,
            **options,
        )


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
            raise ValueError(
                f"a target option reads TARGET:STEPS with TARGET in {list(TARGETS)}, e.g. euler:8, euler:2,4,8 or bootstrap:8; got {text!r}"
            )
        return cls(target, parse_target_steps(steps))

    @property
    def name(self) -> str:
        steps = self.steps if isinstance(self.steps, int) else "-".join(map(str, self.steps))
        return f"{self.target}-{steps}"

    def __str__(self) -> str:
        """The option as typed: ``euler:2,4,8``."""
        steps = self.steps if isinstance(self.steps, int) else ",".join(map(str, self.steps))
        return f"{self.target}:{steps}"

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


@dataclass(frozen=True)
class Recipe:
    """A named way to distil a built-in teacher: the student's optimisation and the distillation settings. Every
    option given beside a recipe (a CLI flag, a sweep run's ``train`` / ``distill`` keys) overrides its value."""

    summary: str
    train: TrainConfig
    distill_options: dict[str, Any]  # DistillSettings fields; built on use, as the settings check with torch

    @property
    def distill(self) -> DistillSettings:
        return DistillSettings(**self.distill_options)


RECIPES: dict[str, Recipe] = {
    "snapflow": Recipe(
        "snapflow's recipe (docs/RESULTS.md, 'One step as good as ten'): the paper's objective and budget with "
        "lambda 3 (2000 steps at lr 3e-5)",
        PAPER_STUDENT_TRAINING,
        {"consistency_weight": 3.0},
    ),
    "paper": Recipe(
        "the paper's settings: alpha 0.5, lambda 0.1, two-step Euler target, prefix frozen; 2000 steps at lr 3e-5",
        PAPER_STUDENT_TRAINING,
        {},
    ),
}
DEFAULT_RECIPE = "snapflow"


def __getattr__(name: str) -> Any:
    """``distill`` and ``train_teacher`` by their old path, kept while ``jobs/sweep/planning.py`` imports them from
    here; they are :mod:`snapflow.training.stages`', imported on first use (this module loads no torch)."""
    if name in ("distill", "train_teacher"):
        from snapflow.training import stages

        return getattr(stages, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = [
    "DEFAULT_RECIPE",
    "DistillSettings",
    "METHODS",
    "RECIPES",
    "Recipe",
    "TARGETS",
    "TargetOption",
    "parse_target_steps",
]
