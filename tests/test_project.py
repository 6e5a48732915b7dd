"""Project wiring: CI runs exactly the README's test command, and no layer outside the policy registry knows MiniVLA."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "src" / "snapflow"


def test_ci_runs_the_readme_test_command_verbatim():
    first_block = re.search(r"```bash\n(.*?)```", (ROOT / "README.md").read_text(), re.S).group(1)
    commands = [line.split("  #")[0].strip() for line in first_block.strip().splitlines()]
    assert len(commands) == 2, "the README opens with exactly two commands: main job, then tests"
    assert commands[1] in (ROOT / ".ci" / "run").read_text().splitlines()


# MiniVLA is one registered built-in policy among others: only its own folder and the registry import it. Elsewhere a
# file may name a policy by its registered string, "minivla" (a CLI help line, a default), never by its classes.
OWNERS = ("policies/minivla/", "policies/factory.py")
NAMES_THE_REGISTERED_STRING = {
    "cli/bench.py": "the help of --architecture: what minivla times",
    "cli/train.py": "the help of --use-image / --image-size, options MiniVLA reads",
    "benchmark/subjects.py": "docstrings: what --architecture minivla times",
    "jobs/demo.py": 'the demo trains the policy registered as "minivla"',
    "jobs/sweep/__init__.py": 'the sweep schema in the docstring: policy = {type = "minivla" | "mlp", ...}',
    "jobs/sweep/schema.py": 'DEFAULT_POLICY = "minivla", the policy type of a sweep that names none',
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
