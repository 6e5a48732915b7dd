"""The README and its guides (``docs/guides/``), as a user meets them: the Python example runs as written, and every
``snapflow ...`` command they show is one the CLI accepts."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
GUIDES = sorted((ROOT / "docs" / "guides").glob("*.md"))


def _python_example() -> str:
    text = (ROOT / "docs" / "guides" / "python-api.md").read_text()
    return re.search(r"```python\n(.*?)```", text, re.S).group(1)


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


def test_every_command_the_readme_and_its_guides_show_parses():
    """Each ``snapflow ...`` line in the code blocks of the README and of the guides it links to is a command line
    the CLI accepts (placeholders in angle brackets filled in)."""
    from snapflow.cli import build_parser

    parser = build_parser()
    text = "\n".join(path.read_text() for path in (README, *GUIDES))
    blocks = re.findall(r"```bash\n(.*?)```", text, re.S)
    commands = [
        re.sub(r"<[^>]*>", "x", line.split("#")[0].replace("\\", " ")).split()
        for block in blocks
        for line in block.replace("\\\n", " ").splitlines()
        if line.strip().startswith("snapflow ")
    ]
    assert len(commands) >= 20
    for words in commands:
        args = parser.parse_args(words[1:])
        assert args.command == words[1]


def test_the_readme_is_short_and_every_link_it_and_its_guides_give_exists():
    """At most 150 lines; every relative link of the README and of the guides names a file or folder that exists
    (anchors aside)."""
    assert len(README.read_text().splitlines()) <= 150
    for page in (README, *GUIDES):
        for target in re.findall(r"\]\(([^)#]+)(?:#[^)]*)?\)", page.read_text()):
            if not target.startswith(("http://", "https://")):
                assert (page.parent / target).exists(), f"{page.relative_to(ROOT)} links to a missing {target}"
