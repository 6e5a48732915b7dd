"""``scripts/serve_closed_loop.py`` as a user runs it: ``snapflow serve`` started as a command, a client of LeRobot's
own gRPC types running a benchmark's episodes in closed loop through it, success counted and each chunk's round trip
timed."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("lerobot", reason="LeRobot is installed by the README's test command; this environment lacks it")
from snapflow.adapters.lerobot_types import PLUGIN_LEROBOT, lerobot_loads_plugins  # noqa: E402

if not lerobot_loads_plugins():
    pytest.skip(f"snapflow serve needs lerobot {PLUGIN_LEROBOT} or newer", allow_module_level=True)

from snapflow.envs.factory import make_benchmark  # noqa: E402
from tests.lerobot_tiny import save_tiny_student  # noqa: E402

SCRIPT = Path(__file__).resolve().parents[2] / "scripts" / "serve_closed_loop.py"


@pytest.mark.slow
def test_a_served_student_runs_meta_world_episodes_in_closed_loop_through_the_server(tmp_path, vlm_directory):
    benchmark = make_benchmark("metaworld")
    # it reads the state's first 4 entries (the hand and the gripper), as snapflow's evaluator gives them
    student = save_tiny_student(vlm_directory, tmp_path / "student", 4, "observation.images.corner", image_size=64)
    output = tmp_path / "served"
    command = [sys.executable, str(SCRIPT), "--policy", str(student), "--env", "metaworld", "--tasks", "reach-v3"]
    # cut at 30 steps of the 500 the task allows: each round trip is what it is from the first chunk on
    command += ["--episodes", "2", "--n-action-steps", "4", "--max-episode-steps", "30", "--output", str(output)]
    finished = subprocess.run(command, capture_output=True, text=True, stdin=subprocess.DEVNULL, timeout=900)
    assert finished.returncode == 0, finished.stdout[-2000:] + finished.stderr[-3000:]
    episodes = [json.loads(line) for line in (output / "episodes.jsonl").read_text().splitlines()]
    assert [(episode["task"], episode["variation"]) for episode in episodes] == [("reach-v3", 0), ("reach-v3", 1)]
    assert benchmark.max_episode_steps > 30
    for episode in episodes:  # a chunk of 4 executed per round trip, until success or the cut
        assert len(episode["round_trip_ms"]) == -(-episode["steps"] // 4) and min(episode["round_trip_ms"]) > 0
        assert episode["success"] or episode["steps"] == 30
    summary = json.loads((output / "summary.json").read_text())
    assert summary["episodes"] == 2 and summary["successes"] == sum(episode["success"] for episode in episodes)
    assert summary["mode"] == "snapflow-1" and summary["round_trip_ms"]["median"] > 0
    assert summary["max_episode_steps"] == 30
    assert summary["versions"]["lerobot"], "the versions it ran under"
    assert "| snapflow-1 | 2 |" in (output / "summary.md").read_text()
