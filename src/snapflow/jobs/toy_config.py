"""The toy experiment's settings: plain Python, read by the CLI before torch loads."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from snapflow.objective.settings import DistillSettings
from snapflow.reporting.records import as_record
from snapflow.training.recipes import DEFAULT_RECIPE, student_settings

#: the distillation settings every toy run records, in this order among its own (the cache keys of the committed
#: comparisons, docs/results/toy-targets*); another setting is recorded where it differs from the toy's default
RECORDED_SETTINGS = ("alpha", "consistency_weight", "method", "target", "target_steps")


def toy_distill_settings(**given: Any) -> DistillSettings:
    """The toy's distillation settings: snapflow's recipe (:data:`~snapflow.training.recipes.DEFAULT_RECIPE`) with
    every parameter trained (``freeze_prefix`` false: the toy's MLP always trained its observation encoder too), each
    setting ``given`` overriding them."""
    return student_settings(DEFAULT_RECIPE, distill={"freeze_prefix": False, **given})[1]


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


__all__ = ["RECORDED_SETTINGS", "ToyConfig", "toy_distill_settings"]
