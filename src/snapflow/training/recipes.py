"""What a student is distilled with: the named recipes, each a student's training and distillation settings
(:class:`~snapflow.objective.settings.DistillSettings`, declared with the objectives and re-exported here, where the
runs and the CLI read it), and the SnapFlow target options.

Plain Python at import (the CLI reads these settings before torch loads). The stage that distils a built-in teacher
with them is :func:`snapflow.training.stages.distill`.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, replace
from typing import Any

from snapflow.errors import InvalidInputError
from snapflow.objective.options import PAPER_ALPHA, PAPER_CONSISTENCY_WEIGHT, PAPER_TARGET_STEPS, target_stages
from snapflow.objective.registry import targets
from snapflow.objective.settings import DistillSettings
from snapflow.training.config import PAPER_STUDENT_TRAINING, TrainConfig, paper_training


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
        if self.target == "energy":
            return f"energy term, K = {self.steps}"
        return f"K = {self.steps}" if isinstance(self.steps, int) else "K = " + " -> ".join(map(str, self.steps))

    def settings(self, base: DistillSettings | None = None) -> DistillSettings:
        """``base`` (default: the paper's settings) with this target."""
        return replace(base or DistillSettings(), target=self.target, target_steps=self.steps)

    @property
    def teacher_passes(self) -> float:
        """No-grad passes per one-step row (averaged over a schedule's stages); each row adds one gradient pass (the
        energy target adds more rows to that pass, and no no-grad pass)."""
        if self.target == "bootstrap":
            return 2.0
        stages = target_stages(self.steps)
        return sum(stages) / len(stages)


#: the SnapFlow targets whose objective computes no target, and so spends no teacher pass, at lambda 0
UNTARGETED_AT_LAMBDA_0 = ("euler", "energy")


def teacher_passes_spent(settings: DistillSettings) -> float:
    """No-grad teacher passes per one-step row that ``settings`` spend: their target's
    (:attr:`TargetOption.teacher_passes`), or none at lambda 0 where the objective computes no target."""
    if settings.consistency_weight == 0 and settings.target in UNTARGETED_AT_LAMBDA_0:
        return 0.0
    return TargetOption(settings.target, settings.target_steps).teacher_passes


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
    "modes": Recipe(
        "snapflow's recipe with an energy term that keeps a multimodal teacher's modes (docs/concepts/recipes.md, "
        "'A recipe that keeps modes'): target energy, lambda 0.3, energy weight 16 over 3 one-step samples an "
        f"observation ({_PAPER_BUDGET})",
        PAPER_STUDENT_TRAINING,
        {
            "consistency_weight": 0.3,
            "target": "energy",
            "objective_options": {"energy_weight": 16.0, "energy_samples": 3},
        },
    ),
    "modes-lean": Recipe(
        "the modes recipe at a leaner step (docs/concepts/recipes.md, 'A recipe that keeps modes'): target energy, "
        "lambda 0 (no consistency target, so no teacher pass), alpha 0.6, energy weight 16 over 4 one-step samples an "
        f"observation ({_PAPER_BUDGET})",
        PAPER_STUDENT_TRAINING,
        {
            "alpha": 0.6,
            "consistency_weight": 0.0,
            "target": "energy",
            "objective_options": {"energy_weight": 16.0, "energy_samples": 4},
        },
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
    "teacher_passes_spent",
]
