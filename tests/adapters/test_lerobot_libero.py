"""LIBERO demonstrations as a LeRobotDataset: `snapflow collect --env libero --lerobot-dataset` writes the scripted
experts' episodes with LeRobot's own writer, LeRobot's ``LeRobotDataset`` reads them back, and their features are
those LeRobot's own LIBERO environment gives a policy, so ``lerobot-eval --env.type=libero`` runs a policy trained on
them unchanged."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from snapflow.data.demonstrations import Demonstrations

pytest.importorskip("lerobot")
IMAGE_SIZE = 32


@pytest.fixture(scope="module")
def collected(tmp_path_factory):
    """Two LIBERO-Spatial demonstrations of one task with 32-pixel images, as npz and as a LeRobotDataset."""
    root = tmp_path_factory.mktemp("libero")
    command = [sys.executable, "-m", "snapflow.cli", "collect", "--env", "libero", "--tasks", "libero_spatial_0"]
    command += ["--episodes", "2", "--image-size", str(IMAGE_SIZE), "--output", str(root / "data")]
    command += ["--lerobot-dataset", str(root / "lerobot"), "--no-progress"]
    finished = subprocess.run(command, capture_output=True, text=True, stdin=subprocess.DEVNULL, timeout=600)
    assert finished.returncode == 0, finished.stderr[-3000:]
    return root


@pytest.mark.slow
def test_lerobot_reads_back_both_cameras_state_and_actions(collected):
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    demonstrations = Demonstrations.load(collected / "data")
    assert (
        demonstrations.env == "libero"
        and [e.variation for e in demonstrations.episodes] == [0, 1][: len(demonstrations.episodes)]
    )
    assert demonstrations.states.shape[1] == 8 and demonstrations.actions.shape[1] == 7
    assert set(demonstrations.extra_images) == {"image2"}
    dataset = LeRobotDataset("local/lerobot", root=collected / "lerobot")
    assert dataset.num_episodes == len(demonstrations.episodes) == 2
    assert dataset.num_frames == len(demonstrations.states)
    assert dataset.fps == 20
    last = len(demonstrations.states) - 1
    for row in (0, last):
        frame = dataset[row]
        np.testing.assert_allclose(frame["observation.state"].numpy(), demonstrations.states[row], atol=1e-6)
        np.testing.assert_allclose(frame["action"].numpy(), demonstrations.actions[row], atol=1e-6)
        for key, frames in (("image", demonstrations.images), ("image2", demonstrations.extra_images["image2"])):
            image = frame[f"observation.images.{key}"]  # LeRobot gives CHW floats in [0, 1]
            np.testing.assert_allclose(image.permute(1, 2, 0).numpy() * 255, frames[row], atol=1)
        assert frame["task"] == demonstrations.instructions["libero_spatial_0"]


@pytest.mark.slow
def test_its_features_are_those_lerobots_libero_environment_gives_a_policy(collected):
    """The dataset's policy features equal LeRobot's LiberoEnv at the same image size after LeRobot's LIBERO
    processor (two cameras, the 8-D state it assembles from the robot's state), and its action is LeRobot's 7-D."""
    from lerobot.configs.types import FeatureType, PolicyFeature
    from lerobot.datasets.lerobot_dataset import LeRobotDatasetMetadata
    from lerobot.envs.configs import LiberoEnv
    from lerobot.envs.utils import env_to_policy_features
    from lerobot.processor.env_processor import LiberoProcessorStep

    from snapflow.adapters.lerobot.dataset import policy_features

    metadata = LeRobotDatasetMetadata("local/lerobot", root=collected / "lerobot")
    ours = policy_features(metadata.features)
    environment = env_to_policy_features(LiberoEnv(observation_height=IMAGE_SIZE, observation_width=IMAGE_SIZE))
    by_type: dict = {}
    for key, feature in environment.items():
        by_type.setdefault(feature.type, {})[key] = feature
    theirs = {
        key: f for group in LiberoProcessorStep().transform_features(by_type).values() for key, f in group.items()
    }
    assert ours == theirs
    assert theirs["observation.state"] == PolicyFeature(type=FeatureType.STATE, shape=(8,))
    assert theirs["observation.images.image2"].shape == (3, IMAGE_SIZE, IMAGE_SIZE)
    assert ours["action"] == PolicyFeature(type=FeatureType.ACTION, shape=(7,))
