"""Project wiring: CI runs exactly the README's test command."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_ci_runs_the_readme_test_command_verbatim():
    first_block = re.search(r"```bash\n(.*?)```", (ROOT / "README.md").read_text(), re.S).group(1)
    commands = [line.split("  #")[0].strip() for line in first_block.strip().splitlines()]
    assert len(commands) == 2, "the README opens with exactly two commands: main job, then tests"
    assert commands[1] in (ROOT / ".ci" / "run").read_text().splitlines()
