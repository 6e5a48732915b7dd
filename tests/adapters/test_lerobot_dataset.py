"""`snapflow collect --lerobot-dataset`: the same Meta-World demonstrations as the npz, written by LeRobot's own
writer, read back by LeRobot's own ``LeRobotDataset``."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

pytest.importorskip("lerobot", reason="LeRobot is installed by the README's test command; this environment lacks it")
pytest.importorskip("metaworld")

from snapflow.data.demonstrations import Demonstrations  # noqa: E402

TASKS = ["reach-v3", "button-press-topdown-v3"]
IMAGE_SIZE = 32


@pytest.fixture(scope="module")
def collected(tmp_path_factory):
    """Two episodes of two tasks with 32-pixel images, as npz and as a LeRobotDataset, by the CLI."""
    folder = tmp_path_factory.mktemp("collect")
    command = [
        sys.executable,
        "-m",
        "snapflow.cli",
        "collect",
        "--tasks",
        ",".join(TASKS),
        "--episodes",
        "2",
        "--image-size",
        str(IMAGE_SIZE),
        "--output",
        str(folder / "npz"),
        "--lerobot-dataset",
        str(folder / "lerobot"),
        "--no-progress",
    ]
    finished = subprocess.run(command, capture_output=True, text=True, timeout=600)
    assert finished.returncode == 0, finished.stderr
    assert "as a LeRobotDataset" in finished.stdout
    return folder


@pytest.mark.slow
def test_lerobot_reads_back_the_episodes_the_npz_holds(collected):
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    demonstrations = Demonstrations.load(collected / "npz")
    dataset = LeRobotDataset("local/lerobot", root=collected / "lerobot")
    camera = "observation.images.corner"

    assert dataset.num_episodes == len(demonstrations.episodes) == 4
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
