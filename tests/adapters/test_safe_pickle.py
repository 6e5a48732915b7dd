"""The allow-list unpickler ``snapflow serve`` reads LeRobot's protocol messages with: every message LeRobot's client
and server send reads back equal, and a payload naming any other callable is refused before it runs."""

from __future__ import annotations

import os
import pickle
import time

import numpy as np
import pytest
import torch

helpers = pytest.importorskip("lerobot.async_inference.helpers", reason="LeRobot's async inference")
from lerobot.configs.types import FeatureType, PolicyFeature  # noqa: E402

from snapflow.adapters.lerobot.safe_pickle import RefusedPayload, loads  # noqa: E402


def test_the_protocols_messages_read_back_equal():
    features = {
        "observation.state": PolicyFeature(FeatureType.STATE, (6,)),
        "observation.images.front": PolicyFeature(FeatureType.VISUAL, (3, 64, 64)),
    }
    specs = helpers.RemotePolicyConfig("snapflow_smolvla", "run/lerobot_policy", features, 10, "cpu", {"a": "b"})
    assert loads(pickle.dumps(specs)) == specs
    raw = {"shoulder.pos": 0.25, "gripper.pos": np.float32(1.5), "task": "stack the blocks"}
    raw |= {"front": np.arange(2 * 3 * 3, dtype=np.uint8).reshape(2, 3, 3), "state": torch.arange(4.0)}
    observation = helpers.TimedObservation(timestamp=time.time(), observation=raw, timestep=7, must_go=True)
    for protocol in (pickle.DEFAULT_PROTOCOL, pickle.HIGHEST_PROTOCOL):  # LeRobot pickles with the default
        read = loads(pickle.dumps(observation, protocol=protocol))
        assert (read.timestep, read.must_go, read.observation["task"]) == (7, True, "stack the blocks")
        np.testing.assert_array_equal(read.observation["front"], raw["front"])
        assert torch.equal(read.observation["state"], raw["state"]) and read.observation["gripper.pos"] == 1.5
    actions = [helpers.TimedAction(timestamp=1.0, timestep=step, action=torch.randn(6)) for step in range(3)]
    assert all(
        torch.equal(a.get_action(), b.get_action()) for a, b in zip(loads(pickle.dumps(actions)), actions, strict=True)
    )


class RunsACommand:
    def __reduce__(self):
        return os.system, ("touch should-not-exist",)


class BuildsAnotherClass:
    def __reduce__(self):
        return torch.nn.Linear, (2, 2)


@pytest.mark.parametrize("payload", [RunsACommand(), BuildsAnotherClass(), [1, {"nested": RunsACommand()}]])
def test_anything_else_is_refused_by_name_before_it_runs(payload, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(RefusedPayload, match="refused a message that calls .*: not a type LeRobot's protocol sends"):
        loads(pickle.dumps(payload))
    assert not (tmp_path / "should-not-exist").exists()


class HidesACommandInAStorage:
    """The global torch pickles a tensor's storage with, whose bytes it reads by ``torch.load(weights_only=False)``."""

    def __reduce__(self):
        return torch.storage._load_from_bytes, (pickle.dumps(RunsACommand()),)


def test_a_tensor_storage_is_read_by_torchs_weights_only_unpickler(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert torch.equal(loads(pickle.dumps(torch.arange(3.0))), torch.arange(3.0))
    with pytest.raises(pickle.UnpicklingError):
        loads(pickle.dumps(HidesACommandInAStorage()))
    assert not (tmp_path / "should-not-exist").exists()
