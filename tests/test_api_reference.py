"""The Python API reference (``docs/reference/api.md``) covers what a developer reaches for, and its examples run.

It renders every module of :data:`COVERED` (the LeRobot adapters, the student types, the plugin and the trainer among
them), each main entry point of :data:`ENTRY_POINTS` has an ``Examples:`` section, and those that run without LeRobot
run as doctests, as written: their own imports, no flag beyond those they carry, any failure fails. The docstrings are
read from the source, so that checking wrap_policy's example imports no LeRobot.
"""

from __future__ import annotations

import ast
import doctest
import importlib
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
API = ROOT / "docs" / "reference" / "api.md"

#: the modules the reference renders, by what a developer looks for in it
COVERED = {
    "snapflow.protocol": "the protocol a policy speaks",
    "snapflow.flow.modes": "sampling modes",
    "snapflow.flow.solver": "the Euler sampler",
    "snapflow.objective.snapflow": "the objective",
    "snapflow.nn.snapflow_policy": "the built-in policies' wrapper",
    "snapflow.sources": "opening a policy",
    "snapflow.adapters.lerobot": "the LeRobot adapters",
    "snapflow.adapters.lerobot.plugin": "the student types",
    "lerobot_policy_snapflow": "the plugin distribution",
    "snapflow.training.trainer": "the trainer",
    "snapflow.training.config": "the trainer's settings",
    "snapflow.inference.fast_paths": "the fast paths",
    "snapflow.inference.formats": "the export formats",
}

#: the main entry points ("module:qualified name", where they are defined) -> whether their example runs here (False:
#: shown as code, since it needs LeRobot and a policy's weights)
ENTRY_POINTS = {
    "snapflow.objective.snapflow:SnapFlowObjective": True,
    "snapflow.nn.snapflow_policy:SnapFlowPolicy": True,
    "snapflow.flow.solver:sample_actions": True,
    "snapflow.flow.modes:SamplingMode.parse": True,
    "snapflow.sources:open_policy": True,
    "snapflow.training.trainer:train": True,
    "snapflow.training.config:TrainConfig": True,
    "snapflow.adapters.lerobot.registry:wrap_policy": False,
}


def _rendered_modules() -> list[str]:
    return re.findall(r"^::: ([\w.]+)", API.read_text(), re.M)


def _source(module: str) -> Path:
    """A module's file under src/ (or the plugin's folder), found without importing it or its package."""
    parts = module.split(".")
    base = ROOT / "src" if parts[0] == "snapflow" else ROOT / "plugins" / "lerobot_policy_snapflow"
    for candidate in (base.joinpath(*parts).with_suffix(".py"), base.joinpath(*parts, "__init__.py")):
        if candidate.is_file():
            return candidate
    raise FileNotFoundError(module)


def _docstring(entry: str) -> str:
    """The docstring of ``module:Class.method`` as written in its source."""
    module, qualified = entry.split(":")
    node: ast.AST = ast.parse(_source(module).read_text())
    for name in qualified.split("."):
        node = next(
            child
            for child in ast.iter_child_nodes(node)
            if isinstance(child, ast.ClassDef | ast.FunctionDef) and child.name == name
        )
    return ast.get_docstring(node) or ""


def test_the_reference_renders_every_covered_module():
    rendered = _rendered_modules()
    assert not [module for module in COVERED if module not in rendered]
    for module in rendered:  # and every module it renders exists where mkdocs.yml's paths find it
        _source(module)


@pytest.mark.parametrize("entry", ENTRY_POINTS)
def test_each_main_entry_point_has_an_example(entry):
    module = entry.split(":")[0]
    assert any(module == rendered or module.startswith(f"{rendered}.") for rendered in _rendered_modules()), entry
    examples = re.split(r"^Examples:\n", _docstring(entry), flags=re.M)
    assert len(examples) == 2, f"{entry} has no Examples: section"
    code = ">>> " if ENTRY_POINTS[entry] else "```python\n"
    assert code in examples[1], f"{entry}'s Examples: section holds no {code.strip()!r} example"


@pytest.mark.parametrize("entry", [entry for entry, runs in ENTRY_POINTS.items() if runs])
def test_the_examples_run_as_written(entry):
    module_name, qualified = entry.split(":")
    module = importlib.import_module(module_name)
    target = module
    for name in qualified.split("."):
        target = getattr(target, name)
    # recurse=False: this object's own docstring; fresh globals: an example imports what it uses
    tests = doctest.DocTestFinder(recurse=False).find(target, entry, module=module, globs={})
    assert tests and tests[0].examples, f"{entry} has no doctest"
    runner = doctest.DocTestRunner()
    for test in tests:
        runner.run(test, out=lambda text: pytest.fail(f"{entry}'s example failed:\n{text}"))
    assert runner.summarize(verbose=False).failed == 0
