"""What a student is distilled with: the settings of a distillation run (shared by every policy family) and the named
recipes, each a student's training and distillation settings.

Plain Python at import (the CLI reads these settings before torch loads); the objective is built on demand. The stage
that distils a built-in teacher with them is :func:`snapflow.training.stages.distill`.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import MISSING, dataclass, fields, replace
from typing import TYPE_CHECKING, Any

from snapflow.errors import InvalidInputError
from snapflow.objective.options import (
    PAPER_ALPHA,
    PAPER_CONSISTENCY_WEIGHT,
    PAPER_TARGET_STEPS,
    TeacherVelocity,
    target_stages,
)
from snapflow.objective.registry import OBJECTIVES, ObjectiveType, make_objective, methods, targets
from snapflow.reporting.records import added_option
from snapflow.training.config import PAPER_STUDENT_TRAINING, TrainConfig, paper_training

if TYPE_CHECKING:
    from snapflow.flow.time_sampling import TimeSampler
    from snapflow.objective.base import TwoBranchObjective


@dataclass(frozen=True)
class DistillSettings:
    """The paper's defaults: SnapFlow, its alpha and lambda (:data:`~snapflow.objective.options.PAPER_ALPHA`,
    :data:`~snapflow.objective.options.PAPER_CONSISTENCY_WEIGHT`), no clamp, prefix (VLM) frozen, phi_s attached,
    two-step Euler target (:data:`~snapflow.objective.options.PAPER_TARGET_STEPS`).

    ``method`` picks the one-step objective (:mod:`snapflow.objective.registry`; the baselines share alpha and
    lambda); ``teacher_velocity`` and ``target_time`` exist for the paper's ablations (conditional velocity; no
    target-time embedding). SnapFlow's target is ``target="euler"`` (the average of ``target_steps`` Euler velocities;
    a list of them is a schedule over equal stages of training) or ``target="bootstrap"`` (built from the model's own
    half-jumps, reaching ``target_steps`` Euler steps at three passes per row; see
    :mod:`snapflow.objective.bootstrap`). ``intermediate_jumps`` is the share of SnapFlow's one-step rows that jump
    between inner times (t, s) instead of 1 -> 0. ``time_shift`` pushes the flow-matching rows' times toward noise
    (:class:`~snapflow.flow.time_sampling.ShiftedTimeSampler`; 1 keeps the policy's own): with ``alpha=1`` and no
    consistency term it is arXiv 2606.05737's high-noise-biased fine-tuning at 4. ``objective_options`` holds the chosen objective's options that no
    field here holds (e.g. meanflow's ``adaptive_power``; absent: the objective's default). The objective is passed
    the options it declares, from their fields or ``objective_options``; an option of another objective must keep its
    default.
    """

    alpha: float = PAPER_ALPHA
    consistency_weight: float = PAPER_CONSISTENCY_WEIGHT
    teacher_velocity_clamp: float | None = None
    freeze_prefix: bool = True
    method: str = "snapflow"
    teacher_velocity: TeacherVelocity = "marginal"
    target_time: bool = True
    target: str = "euler"
    target_steps: int | tuple[int, ...] = PAPER_TARGET_STEPS
    intermediate_jumps: float = 0.0
    time_shift: float = added_option(1.0)
    # left out of the hash, which a dict cannot join (jobs holding these settings are hashed); equality still sees it
    objective_options: dict[str, Any] = added_option(default_factory=dict, hash=False)

    def __post_init__(self) -> None:
        if isinstance(self.target_steps, list):  # as read from TOML or JSON
            object.__setattr__(self, "target_steps", tuple(self.target_steps))
        self._passed_options()  # names, before torch loads, what the chosen objective does not take
        from snapflow.flow.time_sampling import BetaTimeSampler

        self.objective(BetaTimeSampler())  # the objective checks its own values

    @property
    def trains_jump(self) -> bool:
        """Whether these settings train a one-step jump at all: some consistency rows (alpha < 1), weighted
        (lambda > 0). Without, they fine-tune the flow-matching velocity only, to be sampled as ``naive`` or
        ``teacher-N``."""
        return self.alpha < 1 and self.consistency_weight > 0

    @property
    def objective_type(self) -> ObjectiveType:
        """The registered objective that ``method`` and ``target`` pick."""
        if self.target not in targets():
            raise InvalidInputError(f"unknown SnapFlow target {self.target!r}; choose one of {list(targets())}")
        if self.method not in methods():
            raise InvalidInputError(f"unknown distillation method {self.method!r}; choose one of {list(methods())}")
        default_target = _DEFAULTS["target"]  # what a method without targets is picked at
        for entry in OBJECTIVES.values():
            if entry.method == self.method and (entry.target or default_target) == self.target:
                return entry
        offering = [entry.method for entry in OBJECTIVES.values() if entry.target == self.target]
        raise InvalidInputError(f"the {self.target} target is an option of the {' and '.join(offering)} method only")

    def _passed_options(self) -> dict[str, Any]:
        """The options the chosen objective is passed beyond alpha and lambda: each it declares that these settings
        hold, as a field or in ``objective_options``. A field that only other objectives take must be at its default."""
        chosen = self.objective_type
        for name in self.objective_options:
            if name in _DEFAULTS:
                raise InvalidInputError(f"{name} is a setting of its own: set it, not objective_options[{name!r}]")
            if name not in chosen.options:
                raise InvalidInputError(f"{name} is not an option of the {chosen.name} objective")
        declared = {option for entry in OBJECTIVES.values() for option in entry.options}
        for name, default in _DEFAULTS.items():
            if name in declared and name not in chosen.options and getattr(self, name) != default:
                raise InvalidInputError(f"{name} is not an option of the {chosen.name} objective")
        held = {name: getattr(self, name) for name in chosen.options if name in _DEFAULTS}
        return {**held, **self.objective_options}

    def objective(self, time_sampler: TimeSampler) -> TwoBranchObjective:
        """The chosen loss with these settings and the policy's own FM time distribution (shifted by
        ``time_shift``)."""
        from snapflow.flow.time_sampling import shifted

        return make_objective(
            self.objective_type.name,
            alpha=self.alpha,
            consistency_weight=self.consistency_weight,
            time_sampler=shifted(time_sampler, self.time_shift),
            **self._passed_options(),
        )


# each setting's default: what an option the chosen objective does not take must hold
_DEFAULTS = {
    field.name: field.default if field.default_factory is MISSING else field.default_factory()
    for field in fields(DistillSettings)
}


def parse_target_steps(text: str) -> int | tuple[int, ...]:
    """``8``, or a schedule ``2,4,8``."""
    try:
        steps = tuple(int(k) for k in text.split(","))
    except ValueError:
        raise InvalidInputError(
            f"target steps must be integers (8, or a schedule such as 2,4,8), got {text!r}"
        ) from None
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
        if target not in targets() or not steps:
            raise InvalidInputError(
                f"a target option reads TARGET:STEPS with TARGET in {list(targets())}, e.g. euler:8, euler:2,4,8 or bootstrap:8; got {text!r}"
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


# both recipes train the student on the paper's budget
_PAPER_BUDGET = f"{PAPER_STUDENT_TRAINING.steps} steps at lr {PAPER_STUDENT_TRAINING.learning_rate:g}"
RECIPES: dict[str, Recipe] = {
    "snapflow": Recipe(
        "snapflow's recipe (docs/results/metaworld.md, 'One step as good as ten'): the paper's objective and budget with "
        f"lambda 3 ({_PAPER_BUDGET})",
        PAPER_STUDENT_TRAINING,
        {"consistency_weight": 3.0},
    ),
    "paper": Recipe(
        f"the paper's settings: alpha {PAPER_ALPHA}, lambda {PAPER_CONSISTENCY_WEIGHT}, {PAPER_TARGET_STEPS}-step "
        f"Euler target, prefix frozen; {_PAPER_BUDGET}",
        PAPER_STUDENT_TRAINING,
        {},
    ),
}
DEFAULT_RECIPE = "snapflow"
# snapflow's recipe is measured on built-in policies; a LeRobot student starts from the paper's
LEROBOT_RECIPE = "paper"


def student_settings(
    recipe: str | None = None,
    lerobot: bool = False,
    train: Mapping[str, Any] | None = None,
    distill: Mapping[str, Any] | None = None,
) -> tuple[TrainConfig, DistillSettings]:
    """What a student is distilled with: the recipe named ``recipe`` (default: :data:`DEFAULT_RECIPE` for a built-in
    teacher, :data:`LEROBOT_RECIPE` for a LeRobot policy), each field given in ``train`` (:class:`TrainConfig`) and
    ``distill`` (:class:`DistillSettings`) overriding the recipe's; ``distill``'s ``objective_options`` join the
    recipe's. A LeRobot student trains with the paper's LeRobot optimisation
    (:func:`snapflow.training.config.paper_training`) whatever the recipe: the recipes' budgets are the built-in
    policies'."""
    chosen = RECIPES[recipe or (LEROBOT_RECIPE if lerobot else DEFAULT_RECIPE)]
    base_train = paper_training() if lerobot else chosen.train
    options = {**chosen.distill_options, **(distill or {})}
    joined = {**chosen.distill_options.get("objective_options", {}), **options.get("objective_options", {})}
    if joined:
        options["objective_options"] = joined
    return replace(base_train, **(train or {})), DistillSettings(**options)


__all__ = [
    "DEFAULT_RECIPE",
    "DistillSettings",
    "LEROBOT_RECIPE",
    "RECIPES",
    "Recipe",
    "TargetOption",
    "parse_target_steps",
    "student_settings",
]
