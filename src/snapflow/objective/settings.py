"""The settings of a distillation run, declared once: :class:`DistillSettings`. ``snapflow distill`` and a sweep's
students build them from a recipe (:mod:`snapflow.training.recipes`), a LeRobot student's config nests them as its
``distill`` field (what ``lerobot-train`` distils it with), and the toy experiment holds them too.

Plain Python at import (the CLI reads these settings before torch loads); the objective is built on demand. Their
fields are annotated with types that LeRobot's config parser (draccus) decodes, so a student's ``config.json`` and
``--policy.distill.<field>`` flags read them.
"""

from __future__ import annotations

from dataclasses import MISSING, dataclass, fields
from typing import TYPE_CHECKING, Any

from snapflow.errors import InvalidInputError
from snapflow.objective.options import PAPER_ALPHA, PAPER_CONSISTENCY_WEIGHT, PAPER_TARGET_STEPS, TeacherVelocity
from snapflow.objective.registry import OBJECTIVES, ObjectiveType, make_objective, methods, targets
from snapflow.reporting.records import added_option

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
    consistency term it is arXiv 2606.05737's high-noise-biased fine-tuning at 4. ``rtc_max_delay`` > 0 trains
    real-time chunking in (:mod:`snapflow.objective.known_prefix`, LeRobot's ``rtc_training_max_delay``): each row's
    first 0..``rtc_max_delay`` actions given as known, so the jump continues a previous chunk's prefix (a policy
    whose time enters each action: SmolVLA's). ``objective_options`` holds the chosen objective's options that no
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
    rtc_max_delay: int = added_option(0)
    # left out of the hash, which a dict cannot join (jobs holding these settings are hashed); equality still sees it
    objective_options: dict[str, Any] = added_option(default_factory=dict, hash=False)

    def __post_init__(self) -> None:
        if isinstance(self.target_steps, list):  # as read from TOML or JSON
            object.__setattr__(self, "target_steps", tuple(self.target_steps))
        if isinstance(self.rtc_max_delay, bool) or not isinstance(self.rtc_max_delay, int) or self.rtc_max_delay < 0:
            raise InvalidInputError(f"rtc_max_delay is a number of actions, 0 or more, got {self.rtc_max_delay!r}")
        self._passed_options()  # names, before torch loads, what the chosen objective does not take
        from snapflow.flow.time_sampling import BetaTimeSampler

        self.objective(BetaTimeSampler())  # the objective checks its own values

    @property
    def trains_jump(self) -> bool:
        """Whether these settings train a one-step jump at all: some consistency rows (alpha < 1), weighted
        (lambda > 0, or the energy target's term, whose weight is positive unless ``objective_options`` sets it 0).
        Without, they fine-tune the flow-matching velocity only, to be sampled as ``naive`` or ``teacher-N``."""
        energy = self.target == "energy" and self.objective_options.get("energy_weight", 1.0) > 0
        return self.alpha < 1 and (self.consistency_weight > 0 or energy)

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

        objective = make_objective(
            self.objective_type.name,
            alpha=self.alpha,
            consistency_weight=self.consistency_weight,
            time_sampler=shifted(time_sampler, self.time_shift),
            **self._passed_options(),
        )
        if not self.rtc_max_delay:
            return objective
        from snapflow.objective.known_prefix import KnownPrefixObjective

        return KnownPrefixObjective(objective, self.rtc_max_delay)  # type: ignore[return-value]


# each setting's default: what an option the chosen objective does not take must hold
_DEFAULTS = {
    field.name: field.default if field.default_factory is MISSING else field.default_factory()
    for field in fields(DistillSettings)
}


__all__ = ["DistillSettings"]
