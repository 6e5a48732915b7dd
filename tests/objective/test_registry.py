"""The objective registry: names, options, and the errors that name what is wrong."""

from __future__ import annotations

import pytest

from snapflow.objective import (
    OBJECTIVES,
    BootstrappedSnapFlowObjective,
    ConsistencyDistillationObjective,
    MeanFlowObjective,
    SnapFlowObjective,
    make_objective,
)
from snapflow.objective.registry import objective_options


def test_registry_maps_names_to_the_objective_classes():
    """The four registered names and their classes."""
    assert OBJECTIVES == {
        "snapflow": SnapFlowObjective,
        "snapflow-bootstrap": BootstrappedSnapFlowObjective,
        "consistency-distillation": ConsistencyDistillationObjective,
        "meanflow": MeanFlowObjective,
    }


def test_options_are_the_constructor_fields():
    """An objective's options are its dataclass's init fields: the shared three plus its own (never private state)."""
    shared = {"alpha", "consistency_weight", "time_sampler"}
    assert objective_options("snapflow") == shared | {
        "teacher_velocity_clamp",
        "teacher_velocity",
        "target_steps",
        "intermediate_jumps",
    }
    assert objective_options("snapflow-bootstrap") == shared | {"target_steps"}
    assert objective_options("consistency-distillation") == shared | {"num_intervals", "ema_decay"}
    assert objective_options("meanflow") == shared | {"adaptive_power"}


def test_unknown_objective_and_option_are_named():
    """An unknown name lists the known ones; an option the objective lacks lists the options it has; a bad value is
    the objective's own named error."""
    for call in (lambda: make_objective("dance"), lambda: objective_options("dance")):
        with pytest.raises(
            ValueError,
            match="unknown objective 'dance'; choose one of snapflow, snapflow-bootstrap, "
            "consistency-distillation, meanflow",
        ):
            call()
    with pytest.raises(
        ValueError,
        match=r"the meanflow objective takes no option ema_decay, target_steps; its options "
        r"are \['adaptive_power', 'alpha', 'consistency_weight', 'time_sampler'\]",
    ):
        make_objective("meanflow", target_steps=4, ema_decay=0.5)
    with pytest.raises(ValueError, match="ema_decay must be in"):
        make_objective("consistency-distillation", ema_decay=1.5)
