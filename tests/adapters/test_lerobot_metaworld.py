"""LeRobot on Meta-World end to end: `snapflow collect --lerobot-dataset` writes the same demonstrations as the npz
with LeRobot's own writer (read back by LeRobot's ``LeRobotDataset``); a SmolVLA teacher trained on it, distilled,
and evaluated closed loop by snapflow's evaluator through LeRobot's processors (the LeRobot guide's chain, short form)."""

from __future__ import annotations

import filecmp
import json
import subprocess
import sys

import numpy as np
import pytest

pytest.importorskip("lerobot", reason="LeRobot is installed by the README's test command; this environment lacks it")
pytest.importorskip("metaworld")

from snapflow.data.demonstrations import Demonstrations  # noqa: E402
from tests.helpers import run_short_lerobot_chain  # noqa: E402

IMAGE_SIZE = 32  # the short chain's


# ~75 s on CI's two cores, paid once for the module's tests: the LeRobot guide's whole chain, each stage at its
# smallest (two tasks, two demonstrations each, a few training steps, one episode a row cut at 10 steps).
@pytest.fixture(scope="module")
def collected(tmp_path_factory):
    """The LeRobot SmolVLA chain of the LeRobot guide (docs/guides/lerobot.md) in its short form (scripts/lerobot-smolvla.sh, SHORT=1): two
    tasks, two demonstrations each with 32-pixel images as npz and as a LeRobotDataset, a tiny SmolVLA teacher,
    its student, and their evaluation."""
    return run_short_lerobot_chain(tmp_path_factory.mktemp("chain"), "mt10")


@pytest.mark.slow
def test_lerobot_reads_back_the_episodes_the_npz_holds(collected):
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    demonstrations = Demonstrations.load(collected / "data")
    dataset = LeRobotDataset("local/lerobot", root=collected / "lerobot")
    camera = "observation.images.corner"

    assert dataset.num_episodes == len(demonstrations.episodes) == 4  # two tasks, two demonstrations each
    assert dataset.num_frames == len(demonstrations.states)
    assert dataset.fps == 80
    assert tuple(dataset.features["observation.state"]["shape"]) == (39,)
    assert tuple(dataset.features["action"]["shape"]) == (4,)
    assert tuple(dataset.features[camera]["shape"]) == (IMAGE_SIZE, IMAGE_SIZE, 3)
    assert set(dataset.meta.stats) >= {"observation.state", "action", camera}
    np.testing.assert_allclose(dataset.meta.stats["action"]["mean"], demonstrations.actions.mean(0), atol=1e-5)

    table = dataset.hf_dataset.with_format("numpy")
    np.testing.assert_array_equal(np.stack(table["observation.state"]), demonstrations.states)
    np.testing.assert_array_equal(np.stack(table["action"]), demonstrations.actions)
    np.testing.assert_array_equal(np.asarray(table["episode_index"]), demonstrations.episode_index)
    for index, episode in enumerate(demonstrations.episodes):
        last = episode.start + episode.length - 1
        frame = dataset[last]
        assert frame["episode_index"].item() == index
        assert frame["task"] == demonstrations.instructions[episode.task]
        # LeRobot hands images back as float CHW in [0, 1]; the PNG it stored is lossless
        image = (frame[camera].permute(1, 2, 0).numpy() * 255).round().astype(np.uint8)
        np.testing.assert_array_equal(image, demonstrations.images[last])


@pytest.mark.slow
def test_a_dataset_root_is_never_written_over(collected):
    info = (collected / "lerobot" / "meta" / "info.json").read_bytes()
    command = [sys.executable, "-m", "snapflow.cli", "collect", "--tasks", "reach-v3", "--episodes", "1"]
    command += ["--output", str(collected / "again"), "--lerobot-dataset", str(collected / "lerobot"), "--no-progress"]
    finished = subprocess.run(command, capture_output=True, text=True, timeout=600)
    assert finished.returncode == 2
    assert "already exists and is not empty; choose another LeRobotDataset root" in finished.stderr
    assert not (collected / "again").exists(), "refused before any episode ran"
    assert (collected / "lerobot" / "meta" / "info.json").read_bytes() == info
    assert not list(collected.glob(".lerobot.tmp-*"))


@pytest.mark.slow
def test_demonstrations_already_in_the_output_are_written_as_a_dataset_not_collected_again(collected, tmp_path):
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    data = collected / "data"
    written = {path.name: path.stat().st_mtime_ns for path in data.iterdir()}
    command = [sys.executable, "-m", "snapflow.cli", "collect", "--tasks", "reach-v3,button-press-topdown-v3"]
    command += ["--image-size", str(IMAGE_SIZE), "--output", str(data), "--no-progress", "--lerobot-dataset"]

    other = subprocess.run([*command, str(tmp_path / "other"), "--episodes", "3"], capture_output=True, text=True)
    assert other.returncode == 2
    assert "already holds other demonstrations (metaworld, 2 tasks, [2] episodes a task, images 32)" in other.stderr
    assert not (tmp_path / "other").exists()
    noisy = subprocess.run(
        [*command, str(tmp_path / "noisy"), "--episodes", "2", "--action-noise", "0.1"], capture_output=True, text=True
    )
    assert noisy.returncode == 2 and "already holds other demonstrations" in noisy.stderr, "collected without noise"
    assert not (tmp_path / "noisy").exists()

    same = subprocess.run([*command, str(tmp_path / "lerobot"), "--episodes", "2"], capture_output=True, text=True)
    assert same.returncode == 0, same.stderr
    assert f"wrote the 4 expert episodes in {data} as a LeRobotDataset" in same.stdout
    assert {path.name: path.stat().st_mtime_ns for path in data.iterdir()} == written, "nothing collected again"
    again = LeRobotDataset("local/lerobot", root=tmp_path / "lerobot").hf_dataset.with_format("numpy")
    first = LeRobotDataset("local/lerobot", root=collected / "lerobot").hf_dataset.with_format("numpy")
    for column in ("observation.state", "action", "episode_index"):
        np.testing.assert_array_equal(np.stack(again[column]), np.stack(first[column]))


@pytest.mark.slow
def test_the_chain_trains_distills_and_evaluates_a_lerobot_smolvla(collected, monkeypatch):
    from lerobot.policies.smolvla.modeling_smolvla import SmolVLAPolicy

    from snapflow.adapters.lerobot.local_vlm import BUNDLED_VLM

    teacher, student = collected / "teacher" / "lerobot_policy", collected / "student" / "lerobot_policy"
    assert json.loads((teacher / "snapflow.json").read_text())["target_time"] is False
    assert json.loads((student / "snapflow.json").read_text())["target_time"] is True
    # the teacher is a plain LeRobot SmolVLA with its SmolVLM inside: LeRobot's own loader takes it from inside it
    with monkeypatch.context() as inside:
        inside.chdir(teacher)
        assert SmolVLAPolicy.from_pretrained(".").config.vlm_model_name == BUNDLED_VLM
    report = json.loads((collected / "eval" / "report.json").read_text())
    rows = report["rows"]
    assert [(row["mode"]) for row in rows.values()] == ["teacher-10", "naive-1", "snapflow-1"]
    for row in rows.values():
        assert set(row["success"]) == {"reach-v3", "button-press-topdown-v3", "mean"}
        assert row["success"]["mean"]["episodes"] == 2
        assert row["offline"]["samples"] > 0
    assert set(report["latency"]) == set(rows)
    assert (collected / "eval" / "report.md").is_file() and list((collected / "eval").glob("*.png"))
    # KEEP: each stage's final checkpoint, kept to commit (the short chain's teacher runs 4 steps, its student 2)
    for stage, last in (("teacher", "step_0000004"), ("student", "step_0000002")):
        kept = collected / "kept" / stage
        assert sorted(path.name for path in kept.iterdir()) == ["kept.json", last]
        assert filecmp.cmp(
            kept / last / "policy.safetensors",
            collected / stage / "checkpoints" / last / "policy.safetensors",
            shallow=False,
        )
