"""Named distillation recipes: `snapflow distill` and the demo start from the default recipe, `--recipe paper` gives
the paper's settings, and every option given beside a recipe overrides its value (CLI and sweep TOML alike)."""

from __future__ import annotations

import json
from dataclasses import asdict, replace

import pytest

from snapflow.cli import main
from snapflow.jobs.demo import PRESETS, with_recipe
from snapflow.jobs.sweep import load_sweep
from snapflow.reporting.records import as_record
from snapflow.training.config import PAPER_STUDENT_TRAINING, paper_training
from snapflow.training.recipes import DEFAULT_RECIPE, LEROBOT_RECIPE, RECIPES, DistillSettings, student_settings
from snapflow.training.stages import train_teacher
from tests.training.fixtures import TINY, synthetic_demonstrations, train_config


def test_the_paper_recipe_is_the_papers_settings():
    paper = RECIPES["paper"]
    assert paper.distill == DistillSettings()  # alpha 0.5, lambda 0.1, two-step Euler target, prefix frozen
    assert asdict(paper.distill)["consistency_weight"] == 0.1 and paper.distill.target_steps == 2
    assert paper.train == PAPER_STUDENT_TRAINING and paper.train.learning_rate == 3e-5


def test_a_student_starts_from_its_familys_recipe_and_each_given_setting_overrides_it():
    assert student_settings() == (RECIPES[DEFAULT_RECIPE].train, RECIPES[DEFAULT_RECIPE].distill)
    # a LeRobot policy: the paper's settings and the paper's LeRobot optimisation, whatever the recipe
    assert student_settings(lerobot=True) == (paper_training(), RECIPES[LEROBOT_RECIPE].distill)
    train, settings = student_settings("snapflow", lerobot=True, train={"steps": 7}, distill={"alpha": 0.3})
    assert train == replace(paper_training(), steps=7)
    assert settings == replace(RECIPES["snapflow"].distill, alpha=0.3)
    options = {"method": "meanflow", "objective_options": {"adaptive_power": 0.5}}
    assert student_settings("paper", distill=options)[1].objective_options == {"adaptive_power": 0.5}


@pytest.fixture(scope="module")
def teacher(tmp_path_factory):
    data = synthetic_demonstrations().save(tmp_path_factory.mktemp("demos"))
    run = tmp_path_factory.mktemp("runs") / "teacher"
    train_teacher(data, run, TINY, train_config(2), progress=False)
    return data, run


def _distilled(data, teacher, output, *options: str) -> tuple[dict, dict]:
    """The student's recorded distillation settings and training settings after a two-step `snapflow distill`."""
    arguments = ["distill", "--teacher", str(teacher), "--data", str(data), "--output", str(output)]
    assert main([*arguments, "--steps", "2", "--batch-size", "8", "--no-progress", *options]) == 0
    metadata = json.loads((output / "checkpoints" / "step_0000002" / "policy.json").read_text())
    return metadata["distill"], json.loads((output / "history.json").read_text())["train_config"]


def test_distill_takes_the_default_recipe_the_paper_one_flag_away_and_options_override(teacher, tmp_path):
    data, run = teacher
    default, default_train = _distilled(data, run, tmp_path / "default")
    assert default == as_record(RECIPES[DEFAULT_RECIPE].distill)
    assert default_train["learning_rate"] == RECIPES[DEFAULT_RECIPE].train.learning_rate
    paper, _ = _distilled(data, run, tmp_path / "paper", "--recipe", "paper")
    assert paper == as_record(RECIPES["paper"].distill)
    overridden, train = _distilled(
        data, run, tmp_path / "overridden", "--recipe", "paper", "--lambda", "0.5", "--train-prefix"
    )
    assert overridden == as_record(replace(RECIPES["paper"].distill, consistency_weight=0.5, freeze_prefix=False))
    assert train["learning_rate"] == RECIPES["paper"].train.learning_rate and train["steps"] == 2


def test_a_sweep_student_starts_from_its_recipe(tmp_path):
    path = tmp_path / "recipes.toml"
    path.write_text("""
name = "recipes"
recipe = "paper"
[runs.teacher]
[runs.paper]
teacher = "teacher"
[runs.default]
teacher = "teacher"
recipe = "snapflow"
[runs.tuned]
teacher = "teacher"
distill = { alpha = 0.3 }
train = { steps = 10 }
[[tables]]
name = "t"
rows = [{ label = "x", run = "paper", mode = "snapflow-1" }]
""")
    runs = load_sweep(path).runs
    assert runs["paper"].distill == RECIPES["paper"].distill and runs["paper"].train == RECIPES["paper"].train
    assert runs["default"].distill == RECIPES["snapflow"].distill and runs["default"].train == RECIPES["snapflow"].train
    assert runs["tuned"].distill == replace(RECIPES["paper"].distill, alpha=0.3)
    assert runs["tuned"].train == replace(RECIPES["paper"].train, steps=10)
    path.write_text(path.read_text().replace('recipe = "snapflow"', 'recipe = "fast"'))
    with pytest.raises(
        ValueError,
        match=r"\[runs.default\]: unknown recipe 'fast'; choose one of \['snapflow', 'paper', 'modes', 'modes-lean'\]",
    ):
        load_sweep(path)


def test_the_demo_trains_its_student_by_the_chosen_recipe():
    fast = PRESETS["fast"]
    assert fast.student == RECIPES[DEFAULT_RECIPE].train and fast.distill == RECIPES[DEFAULT_RECIPE].distill
    paper = with_recipe(fast, "paper")
    assert paper.distill == RECIPES["paper"].distill and paper.student == RECIPES["paper"].train
    full = with_recipe(PRESETS["full"], "paper")
    assert full.student.steps == 2 * RECIPES["paper"].train.steps  # the full preset trains twice as long
    assert with_recipe(fast, DEFAULT_RECIPE) == fast
