"""A new objective is one registration: a throw-away one, registered by this module's fixture alone, distils a built-in
teacher through DistillSettings and through `snapflow distill`, its own option reaching it both ways."""

from __future__ import annotations

import json
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import pytest
import torch
from torch import Tensor

from snapflow.cli import main
from snapflow.flow.time_sampling import BetaTimeSampler, TimeSampler, UniformTimeSampler
from snapflow.objective import OBJECTIVES, OneStepRows, TwoBranchObjective, register_objective
from snapflow.protocol import Context, FlowPolicy
from snapflow.reporting.records import as_record
from snapflow.training.recipes import DEFAULT_RECIPE, RECIPES, DistillSettings
from snapflow.training.stages import distill, train_teacher
from tests.training.fixtures import TINY, synthetic_demonstrations, train_config

NAME = "scaled-velocity"


@dataclass(frozen=True)
class ScaledVelocityObjective(TwoBranchObjective):
    """The jump 1 -> 0 from the noise regresses ``scale`` times the model's own velocity at t = 1 (scale 1: the
    naive one-step Euler jump)."""

    alpha: float = 0.5
    consistency_weight: float = 0.1
    time_sampler: TimeSampler = field(default_factory=BetaTimeSampler)
    scale: float = 1.0

    def __post_init__(self) -> None:
        self._check_weights()
        if self.scale <= 0:
            raise ValueError(f"scale must be positive, got {self.scale}")

    def one_step_rows(
        self,
        policy: FlowPolicy,
        observation: Any,
        context: Context,
        actions: Tensor,
        noise: Tensor,
        generator: torch.Generator | None,
        progress: float,
    ) -> OneStepRows:
        start, end = torch.ones(noise.shape[0], device=noise.device), torch.zeros(noise.shape[0], device=noise.device)
        with torch.no_grad():
            target = self.scale * policy.velocity(noise, start, start, context)
        return OneStepRows(noise, start, end, target)


@pytest.fixture
def registered():
    """The objective registered for one test, and gone after it, so that no other test sees it."""
    register_objective(NAME, ScaledVelocityObjective, options=("scale",))
    yield
    del OBJECTIVES[NAME]


def test_the_settings_take_its_method_and_pass_it_its_option(registered):
    objective = DistillSettings(method=NAME, objective_options={"scale": 0.5}).objective(UniformTimeSampler())
    assert type(objective) is ScaledVelocityObjective and objective.scale == 0.5 and objective.alpha == 0.5
    assert DistillSettings(method=NAME).objective(UniformTimeSampler()).scale == 1.0  # not given: its own default
    with pytest.raises(ValueError, match="scale must be positive, got 0"):
        DistillSettings(method=NAME, objective_options={"scale": 0})
    with pytest.raises(ValueError, match=f"target_steps is not an option of the {NAME} objective"):
        DistillSettings(method=NAME, target_steps=4)
    with pytest.raises(ValueError, match="scale is not an option of the meanflow objective"):
        DistillSettings(method="meanflow", objective_options={"scale": 0.5})


def test_it_distils_through_the_settings_and_the_command_line(registered, tmp_path: Path, capsys):
    """`snapflow distill --method scaled-velocity --objective-option scale=0.5` is the run the settings make, recorded
    with its option; another scale changes the one-step loss."""
    data = synthetic_demonstrations().save(tmp_path / "demos")
    teacher = tmp_path / "teacher"
    train_teacher(data, teacher, TINY, train_config(2), progress=False)
    recipe = RECIPES[DEFAULT_RECIPE]
    settings = replace(recipe.distill, method=NAME, objective_options={"scale": 0.5})
    by_settings = distill(
        teacher, data, tmp_path / "settings", replace(recipe.train, steps=2, batch_size=8), settings, progress=False
    )

    def snapflow_distill(output: Path, *options: str) -> int:
        arguments = ["distill", "--teacher", str(teacher), "--data", str(data), "--output", str(output)]
        return main([*arguments, "--steps", "2", "--batch-size", "8", "--no-progress", "--method", NAME, *options])

    assert snapflow_distill(tmp_path / "half", "--objective-option", "scale=0.5") == 0
    half = json.loads((tmp_path / "half" / "history.json").read_text())["history"]
    # the same run (up to the last bit of float32: repeated runs in one process differ there)
    assert half == [pytest.approx(entry, rel=1e-6) for entry in by_settings["history"]]
    metadata = json.loads((tmp_path / "half" / "checkpoints" / "step_0000002" / "policy.json").read_text())
    assert metadata["distill"] == as_record(settings) and metadata["distill"]["objective_options"] == {"scale": 0.5}
    assert snapflow_distill(tmp_path / "double", "--objective-option", "scale=2") == 0
    double = json.loads((tmp_path / "double" / "history.json").read_text())["history"]
    assert double[-1]["consistency"] != pytest.approx(half[-1]["consistency"], rel=1e-2)
    assert snapflow_distill(tmp_path / "refused", "--objective-option", "shift=1") == 2
    assert f"shift is not an option of the {NAME} objective" in capsys.readouterr().err
