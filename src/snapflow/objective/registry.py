"""Objectives by name, built with keyword options; the settings layer and the CLI read their names from here.

A new objective is a module in this package (a :class:`TwoBranchObjective` dataclass) and one entry below.
"""

from __future__ import annotations

from dataclasses import fields
from typing import Any, Literal, get_args

from snapflow.objective.base import TwoBranchObjective
from snapflow.objective.bootstrap import BootstrappedSnapFlowObjective
from snapflow.objective.consistency_distillation import ConsistencyDistillationObjective
from snapflow.objective.meanflow import MeanFlowObjective
from snapflow.objective.snapflow import SnapFlowObjective

ObjectiveName = Literal["snapflow", "snapflow-bootstrap", "consistency-distillation", "meanflow"]

OBJECTIVES: dict[str, type[TwoBranchObjective]] = {
    "snapflow": SnapFlowObjective,
    "snapflow-bootstrap": BootstrappedSnapFlowObjective,
    "consistency-distillation": ConsistencyDistillationObjective,
    "meanflow": MeanFlowObjective,
}
assert set(OBJECTIVES) == set(get_args(ObjectiveName))


def objective_options(name: str) -> set[str]:
    """The keyword options objective ``name`` takes (its dataclass fields)."""
    if name not in OBJECTIVES:
        raise ValueError(f"unknown objective {name!r}; choose one of {', '.join(OBJECTIVES)}")
    return {field.name for field in fields(OBJECTIVES[name]) if field.init}


def make_objective(name: str, **options: Any) -> TwoBranchObjective:
    """Objective ``name`` built from keyword ``options``; an option it does not take is a named ValueError, and the
    objective checks its values itself."""
    unknown = sorted(set(options) - objective_options(name))
    if unknown:
        raise ValueError(
            f"the {name} objective takes no option {', '.join(unknown)}; its options are {sorted(objective_options(name))}"
        )
    return OBJECTIVES[name](**options)


__all__ = ["OBJECTIVES", "ObjectiveName", "make_objective", "objective_options"]
