"""The registry of objectives: a name -> its class, the method and target that pick it, and the options it takes.

Plain Python: the settings (:class:`snapflow.training.recipes.DistillSettings`) and the CLI read the methods, targets
and options from here before torch loads; an objective's class is imported when first built. A new objective is a
:class:`~snapflow.objective.base.TwoBranchObjective` dataclass in this package and one :func:`register_objective`
call below.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import TYPE_CHECKING, Any

from snapflow._lazy import resolve
from snapflow.errors import InvalidInputError

if TYPE_CHECKING:
    from snapflow.objective.base import TwoBranchObjective


@dataclass(frozen=True)
class ObjectiveType:
    """One registered objective.

    ``method`` is the distillation method that picks it (``DistillSettings.method``, ``snapflow distill --method``);
    ``target`` picks it among its method's objectives (``--target``; None: its method has no other). ``options`` are
    the settings it takes beyond alpha and lambda (which every objective takes): each a field of
    :class:`~snapflow.training.recipes.DistillSettings` of that name, or else an entry of its ``objective_options``.
    The class may be given as ``"module:Class"``, imported when first used, so that reading the registry loads no
    torch.
    """

    name: str
    objective: type | str
    method: str
    target: str | None
    options: tuple[str, ...]

    @property
    def objective_class(self) -> type[TwoBranchObjective]:
        return resolve(self.objective)


OBJECTIVES: dict[str, ObjectiveType] = {}


def register_objective(
    name: str,
    objective: type | str,
    options: tuple[str, ...] = (),
    method: str | None = None,
    target: str | None = None,
) -> None:
    """Add objective ``name``: its class (or ``"module:Class"``), the options the settings pass it, and the method
    (default: ``name``) and target that pick it."""
    if name in OBJECTIVES:
        raise ValueError(f"an objective named {name!r} is registered already")
    OBJECTIVES[name] = ObjectiveType(name, objective, method or name, target, tuple(options))


register_objective(
    "snapflow",
    "snapflow.objective.snapflow:SnapFlowObjective",
    ("teacher_velocity_clamp", "teacher_velocity", "target_steps", "intermediate_jumps"),
    target="euler",
)
register_objective(
    "snapflow-bootstrap",
    "snapflow.objective.bootstrap:BootstrappedSnapFlowObjective",
    ("target_steps",),
    method="snapflow",
    target="bootstrap",
)
register_objective(
    "snapflow-energy",
    "snapflow.objective.energy:EnergySnapFlowObjective",
    ("teacher_velocity_clamp", "teacher_velocity", "target_steps", "energy_weight", "energy_samples"),
    method="snapflow",
    target="energy",
)
register_objective(
    "consistency-distillation",
    "snapflow.objective.consistency_distillation:ConsistencyDistillationObjective",
    ("num_intervals", "ema_decay"),
)
register_objective("meanflow", "snapflow.objective.meanflow:MeanFlowObjective", ("adaptive_power",))


def methods() -> tuple[str, ...]:
    """The distillation methods, in the order their first objective was registered."""
    return tuple(dict.fromkeys(entry.method for entry in OBJECTIVES.values()))


def targets() -> tuple[str, ...]:
    """The targets that pick an objective among its method's, in registration order."""
    return tuple(dict.fromkeys(entry.target for entry in OBJECTIVES.values() if entry.target is not None))


def objective_type(name: str) -> ObjectiveType:
    """The registered objective ``name``, or a ValueError listing the known ones."""
    if name not in OBJECTIVES:
        raise InvalidInputError(f"unknown objective {name!r}; choose one of {', '.join(OBJECTIVES)}")
    return OBJECTIVES[name]


def objective_options(name: str) -> set[str]:
    """The keyword options objective ``name`` takes (its dataclass's init fields)."""
    return {field.name for field in fields(objective_type(name).objective_class) if field.init}


def make_objective(name: str, **options: Any) -> TwoBranchObjective:
    """Objective ``name`` built from keyword ``options``; an option it does not take is a named ValueError, and the
    objective checks its values itself."""
    unknown = sorted(set(options) - objective_options(name))
    if unknown:
        raise InvalidInputError(
            f"the {name} objective takes no option {', '.join(unknown)}; its options are {sorted(objective_options(name))}"
        )
    return objective_type(name).objective_class(**options)


__all__ = [
    "OBJECTIVES",
    "ObjectiveType",
    "make_objective",
    "methods",
    "objective_options",
    "objective_type",
    "register_objective",
    "targets",
]
