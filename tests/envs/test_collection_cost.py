"""``scripts/collection_cost.py``, run as a user runs it from another folder: a LIBERO demonstration's time split
into its parts, written as JSON and Markdown."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

SCRIPT = Path(__file__).resolve().parents[2] / "scripts" / "collection_cost.py"


# ~40 s on CI's two cores: one LIBERO environment with both 64-px cameras, two short expert episodes
@pytest.mark.slow
def test_the_collection_cost_script_splits_a_demonstrations_time_into_its_parts(tmp_path):
    environment = {**os.environ, "MUJOCO_GL": "egl", "SNAPFLOW_MESH_CACHE": str(tmp_path / "meshes")}
    result = subprocess.run(
        [sys.executable, str(SCRIPT), "out", "--tasks", "libero_goal_0", "--episodes", "1", "--env", "libero-lod"],
        cwd=tmp_path,
        env=environment,
        capture_output=True,
        text=True,
    )
    assert result.returncode == 0, result.stderr[-2000:]
    report = json.loads((tmp_path / "out" / "collection_cost.json").read_text())
    (row,) = report["rows"]
    assert report["env"] == "libero-lod" and row["task"] == "libero_goal_0" and row["mean_steps"] > 50
    parts = row["parts"]
    assert parts["reset"] < 0.5, "a training reset keeps the model"
    assert min(parts["physics"], parts["observe"]) > 0 and abs(sum(parts.values()) - row["seconds"]) < 1e-6
    assert "| libero_goal_0 |" in (tmp_path / "out" / "collection_cost.md").read_text()
