"""Static checks of the source tree, run by the README's test command: the layer contract (import-linter, declared in
pyproject.toml) and ruff."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
BIN = Path(sys.executable).parent


def _run(command: list[str], **environment: str) -> subprocess.CompletedProcess:
    return subprocess.run(command, cwd=ROOT, capture_output=True, text=True, env={**os.environ, **environment})


def test_every_package_imports_only_the_layers_below_it():
    result = _run([str(BIN / "lint-imports")])
    assert result.returncode == 0, result.stdout + result.stderr
    assert "3 kept, 0 broken" in result.stdout


# Each contract, shown to catch the back-import it exists for: (module a copy of the package appends an import to,
# the module it imports, what lint-imports then names). The flow-matching math importing the demo job crosses the
# layers; the plugin, its registry and the type declarations, and the training recipes and the LeRobot runs, once
# imported each other in circles.
BACK_IMPORTS = {
    "layers": ("flow/path.py", "snapflow.jobs.demo", "snapflow.flow.path -> snapflow.jobs.demo"),
    "lerobot": (
        "adapters/lerobot/registry.py",
        "snapflow.adapters.lerobot.plugin",
        "- snapflow.adapters.lerobot.registry -> snapflow.adapters.lerobot.plugin",
    ),
    "training": (
        "training/recipes.py",
        "snapflow.training.lerobot",
        "- snapflow.training.recipes -> snapflow.training.lerobot",
    ),
}


@pytest.mark.parametrize("contract", BACK_IMPORTS)
def test_each_contract_catches_the_back_import_it_exists_for(tmp_path, contract):
    module, imported, named = BACK_IMPORTS[contract]
    shutil.copytree(ROOT / "src" / "snapflow", tmp_path / "snapflow")
    with open(tmp_path / "snapflow" / module, "a") as source:
        source.write(f"\nimport {imported}  # a deliberate back-import\n")
    result = _run([str(BIN / "lint-imports")], PYTHONPATH=str(tmp_path))
    assert result.returncode == 1
    assert named in result.stdout


def test_ruff_finds_nothing_to_fix_or_reformat():
    check = _run([str(BIN / "ruff"), "check", "src", "tests"])
    assert check.returncode == 0, check.stdout + check.stderr
    formatted = _run([str(BIN / "ruff"), "format", "--check", "src", "tests"])
    assert formatted.returncode == 0, formatted.stdout + formatted.stderr
