"""The tutorials (``docs/tutorials/``) as a reader follows them: every code block, top to bottom, typed into one shell
at the root of a clone of the repository (Python blocks as that shell's ``python``). A block that needs what a test
machine lacks says so on the line before it (``<!-- needs: gpu -->``, ``hub``, ``robot`` or ``hours``) and is only
checked to parse; a ``text`` block shows what a script prints, and its tutorial's test holds a run to it. The LeRobot
tutorials continue one another (each starts from the first one's student), so they run as one session, in order
(``tests/test_tutorials_lerobot.py``)."""

from __future__ import annotations

import ast
import os
import re
import subprocess
import sys
from dataclasses import dataclass
from itertools import pairwise
from pathlib import Path

import pytest

from snapflow.adapters.lerobot_types import PLUGIN_LEROBOT, lerobot_loads_plugins

ROOT = Path(__file__).resolve().parents[1]
TUTORIALS = ROOT / "docs" / "tutorials"
#: what a block may need that a test machine lacks: it is shown, its commands parse, it does not run
NEEDS = {"gpu", "hub", "robot", "hours"}
#: the language of a block that shows what a script prints: shown, never run
PRINTED = "text"
#: the LeRobot tutorials, each starting from the first one's student: one shell session, in this order
LEROBOT_SESSION = ["distil-lerobot", "serve", "deploy", "onnx"]
ON_THEIR_OWN = ["reproduce-libero", "own-policy"]
#: the most characters of a code line the site shows at desktop width without scrolling its box
CODE_WIDTH = 84


@dataclass(frozen=True)
class Block:
    language: str
    code: str
    needs: str | None


def tutorial_blocks(name: str) -> list[Block]:
    """The fenced code blocks of tutorial ``name``, each with what its marker says it needs."""
    text = (TUTORIALS / f"{name}.md").read_text()
    pattern = r"(?:<!-- needs: (\w+) -->\n)?```(\w*)\n(.*?)```"
    return [Block(language, code, needs or None) for needs, language, code in re.findall(pattern, text, re.S)]


def as_one_shell_session(names: list[str]) -> str:
    """The runnable blocks of the tutorials ``names`` as one bash script, stopping at the first failing command."""
    lines = ["set -euo pipefail"]
    for name in names:
        for block in tutorial_blocks(name):
            if block.needs is None and block.language != PRINTED:
                lines.append(block.code if block.language == "bash" else f"python - <<'PYTHON'\n{block.code}PYTHON")
    return "\n".join(lines) + "\n"


def run_in_a_clone(names: list[str], tmp_path: Path) -> str:
    clone = tmp_path / "snapflow"
    subprocess.run(["git", "clone", "-q", str(ROOT), str(clone)], check=True)
    environment = {**os.environ, "PATH": f"{Path(sys.executable).parent}{os.pathsep}{os.environ['PATH']}"}
    finished = subprocess.run(
        ["bash", "-c", as_one_shell_session(names)],
        cwd=clone,
        env=environment,
        capture_output=True,
        text=True,
        stdin=subprocess.DEVNULL,
        timeout=1800,
    )
    assert finished.returncode == 0, f"{finished.stdout[-2000:]}\n{finished.stderr[-4000:]}"
    return finished.stdout


def test_every_tutorial_runs_here_and_every_block_runs_or_names_what_it_needs():
    from snapflow.cli import build_parser

    assert {path.stem for path in TUTORIALS.glob("*.md")} == set(LEROBOT_SESSION + ON_THEIR_OWN)
    parser = build_parser()
    for name in LEROBOT_SESSION + ON_THEIR_OWN:
        blocks = tutorial_blocks(name)
        assert any(block.needs is None for block in blocks), f"{name}: no block runs"
        for block in blocks:
            assert block.language in {"bash", "python", PRINTED} and block.needs in NEEDS | {None}, (name, block)
            # a line the site shows whole, without scrolling its code box sideways (measured by screenshot)
            assert max(map(len, block.code.splitlines())) <= CODE_WIDTH, (name, block.code)
            if block.language == "python":
                compile(block.code, name, "exec")
            for line in block.code.replace("\\\n", " ").splitlines():
                if line.strip().startswith("snapflow "):
                    words = line.split("#")[0].split("|")[0].replace("&", "").split()
                    assert parser.parse_args(words[1:]).command == words[1], line


def test_a_block_marked_as_needing_a_gpu_is_left_out_of_the_session():
    session = as_one_shell_session(["deploy"])
    assert "--fast-path deploy" not in session and "snapflow bench --policy" in session


#: the LeRobot tutorials need the student types as LeRobot's own (its plugin), and the kept policies were written
#: by a LeRobot of that line, whose configs an older one refuses
NEEDS_PLUGINS = pytest.mark.skipif(
    not lerobot_loads_plugins(), reason=f"LeRobot loads snapflow's plugin from {PLUGIN_LEROBOT} on"
)


@pytest.mark.slow
@pytest.mark.lerobot
@NEEDS_PLUGINS
def test_the_libero_reproduction_tutorial_runs_top_to_bottom(tmp_path):
    output = run_in_a_clone(["reproduce-libero"], tmp_path)
    assert "| teacher-10 |" in output and "| snapflow-1 |" in output


def stated_output(name: str) -> tuple[dict[str, float], dict[str, tuple[float, float]], list[str]]:
    """What tutorial ``name`` says its script prints: the printed line (its ``text`` block, a dict), each figure with
    its absolute band (the rows ``| `key` | figure | ± band |`` of its table), and the keys in the order their figures
    keep (the page's "in the order `a` < `b` < `c`")."""
    text = (TUTORIALS / f"{name}.md").read_text()
    (printed,) = [ast.literal_eval(block.code) for block in tutorial_blocks(name) if block.language == PRINTED]
    bands = {
        key: (float(figure), float(band))
        for key, figure, band in re.findall(r"^\| `([\w-]+)` \| ([\d.]+) \| ± ([\d.]+) \|", text, re.M)
    }
    order = re.search(r"in the order ((?:`[\w-]+` < )+`[\w-]+`)", text)
    assert order, f"{name}: no order stated"
    return printed, bands, re.findall(r"`([\w-]+)`", order.group(1))


def test_the_own_policy_tutorial_states_one_output_with_a_band_for_every_figure():
    printed, bands, order = stated_output("own-policy")
    assert printed == {key: figure for key, (figure, _) in bands.items()}, "the printed line and the table differ"
    assert sorted(order) == sorted(printed)
    assert all(printed[a] < printed[b] for a, b in pairwise(order)), "the line printed breaks the stated order"


@pytest.mark.slow
def test_the_own_policy_tutorial_runs_as_written_and_prints_what_the_page_says(tmp_path):
    """A run prints each error within the band the page states around the figure it shows, in the page's order."""
    printed, bands, order = stated_output("own-policy")
    output = run_in_a_clone(["own-policy"], tmp_path)
    measured = ast.literal_eval([line for line in output.splitlines() if line.startswith("{")][-1])
    assert measured.keys() == printed.keys(), output
    outside = {
        key: (measured[key], figure, band)
        for key, (figure, band) in bands.items()
        if abs(measured[key] - figure) > band
    }
    assert not outside, f"outside the page's bands (measured, stated, band): {outside}"
    assert all(measured[a] < measured[b] for a, b in pairwise(order)), (order, measured)
