"""The toy experiment's settings: plain Python, read by the CLI before torch loads."""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any

from snapflow.errors import InvalidInputError
from snapflow.objective.settings import DistillSettings
from snapflow.reporting.records import added_option, as_record
from snapflow.training.recipes import RECIPES, student_settings, teacher_passes_spent

#: the distillation settings every toy run records, in this order among its own (the cache keys of the committed
#: comparisons, docs/results/toy-targets*); another setting is recorded where it differs from the toy's default
RECORDED_SETTINGS = ("alpha", "consistency_weight", "method", "target", "target_steps")

#: the recipe the toy's settings start from, named rather than the default: its committed runs' records (their cache
#: keys) list their settings against it, and stay valid whatever the default recipe becomes
TOY_RECIPE = "snapflow"

#: the toy's distributions (:mod:`snapflow.data.toy_shapes`): the mixture of ``num_modes`` Gaussians on a circle, and
#: two concentric rings, held out from tuning
SHAPES = ("mixture", "rings")


def toy_distill_settings(**given: Any) -> DistillSettings:
    """The toy's distillation settings: snapflow's recipe (:data:`TOY_RECIPE`) with
    every parameter trained (``freeze_prefix`` false: the toy's MLP always trained its observation encoder too), each
    setting ``given`` overriding them."""
    return student_settings(TOY_RECIPE, distill={"freeze_prefix": False, **given})[1]


@dataclass(frozen=True)
class ToyConfig:
    """Sizes and schedules of the toy experiment, and its distillation settings (``distill``, default
    :func:`toy_distill_settings`); the defaults run in well under a minute on 2 cores."""

    seed: int = 0
    num_modes: int = 6
    mode_radius: float = 2.0
    teacher_steps: int = 1500
    distill_steps: int = 3000
    batch_size: int = 256
    teacher_lr: float = 2e-3
    distill_lr: float = 1e-3
    distill: DistillSettings = field(default_factory=toy_distill_settings)
    hidden_dim: int = 256
    eval_contexts: int = 12
    samples_per_context: int = 400
    shape: str = added_option("mixture")

    def __post_init__(self) -> None:
        if self.shape not in SHAPES:
            raise InvalidInputError(f"unknown toy shape {self.shape!r}; choose one of {list(SHAPES)}")

    def record(self) -> dict[str, Any]:
        """The settings as a toy run records them (its cache key): the fields in order, ``distill`` in its place as
        :data:`RECORDED_SETTINGS` and each other setting that differs from the toy's default."""
        default = as_record(toy_distill_settings())
        settings = {
            name: value
            for name, value in as_record(self.distill).items()
            if name in RECORDED_SETTINGS or name not in default or default[name] != value
        }
        record: dict[str, Any] = {}
        for name, value in as_record(self).items():
            record.update(settings if name == "distill" else {name: value})
        return record


@dataclass(frozen=True)
class RecipeOption:
    """A row of ``snapflow toy-compare``: a named recipe's distillation settings (:data:`RECIPES`) on the toy, every
    parameter trained as in :func:`toy_distill_settings` (the comparison's own lambda does not apply)."""

    recipe: str

    def __post_init__(self) -> None:
        if self.recipe not in RECIPES:
            raise InvalidInputError(f"unknown recipe {self.recipe!r}; choose one of {list(RECIPES)}")

    @property
    def name(self) -> str:
        return f"recipe-{self.recipe}"

    @property
    def label(self) -> str:
        return f"recipe {self.recipe}"

    def settings(self, base: DistillSettings | None = None) -> DistillSettings:
        """The recipe's settings with every parameter trained; ``base`` is not read."""
        return student_settings(self.recipe, distill={"freeze_prefix": False})[1]

    @property
    def teacher_passes(self) -> float:
        """No-grad passes per one-step row, as its target's
        (:attr:`~snapflow.training.recipes.TargetOption.teacher_passes`); none at lambda 0
        (:func:`~snapflow.training.recipes.teacher_passes_spent`)."""
        return teacher_passes_spent(self.settings())


#: arXiv 2606.05737's high-noise-biased fine-tuning: flow matching alone on times shifted toward noise by this factor
BIASED_TIME_SHIFT = 4.0


@dataclass(frozen=True)
class BiasedOneStep:
    """A row of ``snapflow toy-compare``: no distillation, the teacher fine-tuned by flow matching on times biased
    toward noise (``time_shift`` :data:`BIASED_TIME_SHIFT`, every row flow matching), then sampled in one Euler step
    (its phi_s stays zero, so its jump is that step), as arXiv 2606.05737 does."""

    name = "biased-one-step"
    label = "biased one step (t shift 4)"
    teacher_passes = 0.0

    def settings(self, base: DistillSettings | None = None) -> DistillSettings:
        """``base`` (default: the toy's) with alpha 1 and the noise-biased times."""
        return replace(base or toy_distill_settings(), alpha=1.0, time_shift=BIASED_TIME_SHIFT)


__all__ = [
    "BIASED_TIME_SHIFT",
    "BiasedOneStep",
    "RecipeOption",
    "RECORDED_SETTINGS",
    "SHAPES",
    "ToyConfig",
    "toy_distill_settings",
]
