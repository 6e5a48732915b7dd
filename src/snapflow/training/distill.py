"""The old path of :mod:`snapflow.training.recipes`, kept while ``jobs/sweep/planning.py`` and
``jobs/sweep/schema.py`` import the settings and recipes from here; new code imports them from there."""

from snapflow.training.recipes import DEFAULT_RECIPE, RECIPES, DistillSettings, Recipe

__all__ = ["DEFAULT_RECIPE", "DistillSettings", "RECIPES", "Recipe"]
