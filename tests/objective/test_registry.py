"""The objective registry: names, the methods and targets that pick them, the options the settings pass them, and
the errors that name what is wrong."""

from __future__ import annotations

import pytest

from snapflow.flow import UniformTimeSampler
from snapflow.objective import (
    OBJECTIVES,
    BootstrappedSnapFlowObjective,
    ConsistencyDistillationObjective,
    EnergySnapFlowObjective,
    MeanFlowObjective,
    SnapFlowObjective,
    make_objective,
    register_objective,
)
from snapflow.objective.registry import methods, objective_options, targets
from snapflow.reporting.records import as_record
from snapflow.training.recipes import DistillSettings


def test_registry_maps_names_to_the_objective_classes_and_the_settings_that_pick_them():
    """The five registered names, their classes, and the method and target of each; the methods and targets are
    the registry's."""
    assert {name: entry.objective_class for name, entry in OBJECTIVES.items()} == {
        "snapflow": SnapFlowObjective,
        "snapflow-bootstrap": BootstrappedSnapFlowObjective,
        "snapflow-energy": EnergySnapFlowObjective,
        "consistency-distillation": ConsistencyDistillationObjective,
        "meanflow": MeanFlowObjective,
    }
    assert methods() == ("snapflow", "consistency-distillation", "meanflow")
    assert targets() == ("euler", "bootstrap", "energy")
    picked = {
        (settings.method, settings.target): settings.objective_type.name
        for settings in (
            DistillSettings(),
            DistillSettings(target="bootstrap", target_steps=4),
            DistillSettings(target="energy"),
            DistillSettings(method="consistency-distillation"),
            DistillSettings(method="meanflow"),
        )
    }
    assert picked == {
        ("snapflow", "euler"): "snapflow",
        ("snapflow", "bootstrap"): "snapflow-bootstrap",
        ("snapflow", "energy"): "snapflow-energy",
        ("consistency-distillation", "euler"): "consistency-distillation",
        ("meanflow", "euler"): "meanflow",
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
    assert objective_options("snapflow-energy") == shared | {
        *("teacher_velocity_clamp", "teacher_velocity", "target_steps", "energy_weight", "energy_samples"),
    }
    assert objective_options("consistency-distillation") == shared | {"num_intervals", "ema_decay"}
    assert objective_options("meanflow") == shared | {"adaptive_power"}


def test_each_objective_declares_its_own_options_for_the_settings_to_pass():
    """What a registration declares is the objective's own options, each one its constructor takes."""
    for name, entry in OBJECTIVES.items():
        assert set(entry.options) == objective_options(name) - {"alpha", "consistency_weight", "time_sampler"}, name


def test_an_option_no_setting_holds_reaches_its_objective_through_objective_options():
    """A baseline's own option (no field of the settings) is passed from ``objective_options`` and recorded there;
    absent, the objective keeps its default and the record is the one from before the option existed."""
    settings = DistillSettings(method="consistency-distillation", objective_options={"num_intervals": 4})
    objective = settings.objective(UniformTimeSampler())
    assert isinstance(objective, ConsistencyDistillationObjective)
    assert objective.num_intervals == 4 and objective.ema_decay == ConsistencyDistillationObjective.ema_decay
    assert as_record(settings)["objective_options"] == {"num_intervals": 4}
    assert "objective_options" not in as_record(DistillSettings(method="consistency-distillation"))
    assert DistillSettings(method="meanflow").objective(UniformTimeSampler()).adaptive_power == 1.0


@pytest.mark.parametrize(
    "settings, message",
    [
        ({"method": "dance"}, r"unknown distillation method 'dance'; choose one of \['snapflow', 'consistency-"),
        (
            {"method": "meanflow", "objective_options": {"num_intervals": 4}},
            "num_intervals is not an option of the meanflow",
        ),
        ({"objective_options": {"target_steps": 4}}, "target_steps is a setting of its own"),
        ({"method": "meanflow", "objective_options": {"adaptive_power": -1.0}}, "adaptive_power must be non-negative"),
    ],
)
def test_settings_name_an_option_their_objective_does_not_take(settings, message):
    with pytest.raises(ValueError, match=message):
        DistillSettings(**settings)


def test_a_name_is_registered_once():
    with pytest.raises(ValueError, match="an objective named 'meanflow' is registered already"):
        register_objective("meanflow", MeanFlowObjective)


def test_unknown_objective_and_option_are_named():
    """An unknown name lists the known ones; an option the objective lacks lists the options it has; a bad value is
    the objective's own named error."""
    for call in (lambda: make_objective("dance"), lambda: objective_options("dance")):
        with pytest.raises(
            ValueError,
            match="unknown objective 'dance'; choose one of snapflow, snapflow-bootstrap, snapflow-energy, "
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
