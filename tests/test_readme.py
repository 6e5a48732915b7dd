"""The README's first contact: its Python example runs as written, and its commands are the CLI's."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

README = Path(__file__).resolve().parents[1] / "README.md"


def _python_example() -> str:
    text = README.read_text()
    start = text.index("## Python API")
    section = text[start : text.index("\n## ", start + 1)]
    return re.search(r"```python\n(.*?)```", section, re.S).group(1)


@pytest.mark.slow
def test_the_python_example_runs_as_written_and_samples_every_mode(tmp_path):
    script = tmp_path / "example.py"
    script.write_text(_python_example())
    result = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, cwd=tmp_path, timeout=600)
    assert result.returncode == 0, result.stderr
    errors = dict(line.split(":") for line in result.stdout.strip().splitlines())
    errors = {name.strip(): float(value) for name, value in errors.items()}
    assert set(errors) == {"teacher-10", "naive", "snapflow-1"}
    # the story the example tells: one distilled step lands far nearer the modes than one naive step
    assert errors["snapflow-1"] < 0.7 * errors["naive"] and errors["teacher-10"] < 0.7 * errors["naive"]


def test_every_command_the_readme_shows_parses():
    """Each ``snapflow ...`` line in the README's code blocks is a command line the CLI accepts (placeholders in
    angle brackets filled in)."""
    from snapflow.cli import build_parser

    parser = build_parser()
    blocks = re.findall(r"```bash\n(.*?)```", README.read_text(), re.S)
    commands = [
        re.sub(r"<[^>]*>", "x", line.split("#")[0].replace("\\", " ")).split()
        for block in blocks
        for line in block.replace("\\\n", " ").splitlines()
        if line.strip().startswith("snapflow ")
    ]
    assert len(commands) >= 5
    for words in commands:
        args = parser.parse_args(words[1:])
        assert args.command == words[1]
