"""Static checks of the source tree, run by the README's test command: the layer contract (import-linter, declared in
pyproject.toml) and ruff."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
BIN = Path(sys.executable).parent


def _run(command: list[str], **environment: str) -> subprocess.CompletedProcess:
    return subprocess.run(command, cwd=ROOT, capture_output=True, text=True, env={**os.environ, **environment})


def test_every_package_imports_only_the_layers_below_it():
    result = _run([str(BIN / "lint-imports")])
    assert result.returncode == 0, result.stdout + result.stderr
    assert "3 kept, 0 broken" in result.stdout


def test_the_layer_contract_catches_a_back_import(tmp_path):
    """A copy of the package whose flow-matching math imports the demo job breaks the contract, naming the import."""
    shutil.copytree(ROOT / "src" / "snapflow", tmp_path / "snapflow")
    with open(tmp_path / "snapflow" / "flow" / "path.py", "a") as path_module:
        path_module.write("\nimport snapflow.jobs.demo  # a deliberate back-import\n")
    result = _run([str(BIN / "lint-imports")], PYTHONPATH=str(tmp_path))
    assert result.returncode == 1
    assert "snapflow.flow is not allowed to import snapflow.jobs" in result.stdout
    assert "snapflow.flow.path -> snapflow.jobs.demo" in result.stdout


def test_the_lerobot_contract_catches_the_registry_importing_the_plugin_back(tmp_path):
    """The plugin, the adapter registry and the type declarations once imported each other in a circle; a copy whose
    registry imports the plugin again breaks the contract."""
    shutil.copytree(ROOT / "src" / "snapflow", tmp_path / "snapflow")
    with open(tmp_path / "snapflow" / "adapters" / "lerobot" / "registry.py", "a") as registry:
        registry.write("\nimport snapflow.adapters.lerobot.plugin  # a deliberate back-import\n")
    result = _run([str(BIN / "lint-imports")], PYTHONPATH=str(tmp_path))
    assert result.returncode == 1
    assert "- snapflow.adapters.lerobot.registry -> snapflow.adapters.lerobot.plugin" in result.stdout


def test_the_training_contract_catches_the_recipes_importing_the_lerobot_runs_back(tmp_path):
    """The recipes and the LeRobot runs once imported each other in a circle; a copy whose recipes import the LeRobot
    runs again breaks the contract."""
    shutil.copytree(ROOT / "src" / "snapflow", tmp_path / "snapflow")
    with open(tmp_path / "snapflow" / "training" / "recipes.py", "a") as recipes:
        recipes.write("\nimport snapflow.training.lerobot  # a deliberate back-import\n")
    result = _run([str(BIN / "lint-imports")], PYTHONPATH=str(tmp_path))
    assert result.returncode == 1
    assert "- snapflow.training.recipes -> snapflow.training.lerobot" in result.stdout


def test_ruff_finds_nothing_to_fix_or_reformat():
    check = _run([str(BIN / "ruff"), "check", "src", "tests"])
    assert check.returncode == 0, check.stdout + check.stderr
    formatted = _run([str(BIN / "ruff"), "format", "--check", "src", "tests"])
    assert formatted.returncode == 0, formatted.stdout + formatted.stderr
