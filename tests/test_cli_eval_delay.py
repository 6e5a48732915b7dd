"""`snapflow eval --inference-delay` as a user runs it: a tiny MiniVLA student distilled with known prefixes, evaluated
on Meta-World under a delay with its prefix given (real-time chunking trained in), in a fresh interpreter."""

from __future__ import annotations

import dataclasses
import json
import subprocess
import sys

import pytest

from snapflow.training.recipes import DistillSettings
from snapflow.training.stages import distill, train_teacher
from tests.training.fixtures import TINY, synthetic_demonstrations, train_config


@pytest.mark.slow
def test_eval_runs_a_trained_student_under_an_inference_delay_and_records_the_setting(tmp_path):
    pytest.importorskip("metaworld")
    data = synthetic_demonstrations(episodes_per_task=2).save(tmp_path / "demos")
    config = dataclasses.replace(TINY, chunk_length=8)
    train_teacher(data, tmp_path / "teacher", config, train_config(2), val_fraction=0.2, progress=False)
    settings = DistillSettings(rtc_max_delay=2)
    distill(tmp_path / "teacher", data, tmp_path / "student", train_config(2), settings, progress=False)
    output = tmp_path / "eval"
    command = [
        *(sys.executable, "-c", "import sys; from snapflow.cli import main; sys.exit(main(sys.argv[1:]))"),
        *("eval", "--policy", f"{tmp_path / 'student'}=snapflow-1", "--env", "metaworld", "--tasks", "reach-v3"),
        *("--episodes", "1", "--max-episode-steps", "10", "--n-act", "4", "--inference-delay", "2"),
        *("--rtc", "trained", "--execution-horizon", "5", "--no-progress", "--output", str(output)),
    ]
    result = subprocess.run(command, capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stderr
    report = json.loads((output / "report.json").read_text())
    assert report["rtc"]["delay"] == 2 and report["rtc"]["kind"] == "trained"
    assert report["rtc"]["execution_horizon"] == 5
    assert report["rows"]["snapflow-1"]["success"]["mean"]["episodes"] == 1
    (log,) = (output / "episodes").iterdir()
    assert json.loads(log.read_text().splitlines()[0])["identity"]["rtc"]["kind"] == "trained"
    assert "Inference delay of 2 action(s)" in result.stdout
    switches = report["rows"]["snapflow-1"]["switches"]  # 10 steps, a chunk every 4: switches at steps 4 and 8
    assert switches["switches"] == 2 and switches["jump_at_switches"] >= 0
    assert "## How smoothly the chunks joined" in (output / "report.md").read_text()
    past = [argument if argument != "2" else "3" for argument in command]  # the delay, past the trained prefixes
    refused = subprocess.run(past, capture_output=True, text=True, timeout=600)
    assert refused.returncode == 2 and "at most 2 actions of a previous chunk" in refused.stderr, refused.stderr
