"""GR00T N1.7 from the project's own checkpoint writer to a served and evaluated student, each step a command as a
user types it, from a working directory that holds the data and nothing else: the writer makes the checkpoint and
LeRobot's GrootPolicy over it for a LIBERO dataset, ``snapflow distill --lerobot-train`` writes its student,
``lerobot-train`` steps it, ``snapflow serve`` answers a client of LeRobot's own types with a chunk, and
``snapflow eval`` runs it in LeRobot's LIBERO environment at one step and at its own four."""

from __future__ import annotations

import json
import pickle
import sys
import time
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("lerobot", reason="LeRobot is installed by the README's test command; this environment lacks it")
pytest.importorskip("lerobot.policies.groot.groot_n1_7", reason="LeRobot's GR00T N1.7 arrived in lerobot 0.6")
pytest.importorskip("libero")
grpc = pytest.importorskip("grpc", reason="LeRobot's async extra (lerobot[async]) brings grpcio")

from lerobot.async_inference.configs import PolicyServerConfig  # noqa: E402
from lerobot.async_inference.helpers import RemotePolicyConfig, TimedObservation  # noqa: E402
from lerobot.transport import services_pb2, services_pb2_grpc  # noqa: E402
from lerobot.transport.utils import send_bytes_in_chunks  # noqa: E402
from lerobot.utils.feature_utils import hw_to_dataset_features  # noqa: E402

from tests.helpers import free_loopback_port, run_checked, run_tiny_lerobot_train  # noqa: E402

IMAGE_SIZE = 32  # the tiny checkpoint's
JOINTS = tuple(f"joint_{index}.pos" for index in range(8))  # LIBERO's 8-D proprioception


def _snapflow(*arguments: str, cwd: Path) -> str:
    command = [str(Path(sys.executable).with_name("snapflow")), *arguments, "--no-progress"]
    return run_checked(command, {"MUJOCO_GL": "egl", "HF_HUB_OFFLINE": "1"}, cwd=cwd).stdout


def _one_chunk(folder: Path) -> list:
    """One chunk of the student at ``folder`` through ``snapflow serve``'s server, asked as LeRobot's client asks."""
    from snapflow.adapters.lerobot.serve import start_server

    port = free_loopback_port()
    server, _ = start_server(PolicyServerConfig(host="127.0.0.1", port=port, inference_latency=0.0))
    robot = {**dict.fromkeys(JOINTS, float), "image": (IMAGE_SIZE, IMAGE_SIZE, 3), "image2": (IMAGE_SIZE,) * 2 + (3,)}
    try:
        with grpc.insecure_channel(f"127.0.0.1:{port}") as channel:
            stub = services_pb2_grpc.AsyncInferenceStub(channel)
            stub.Ready(services_pb2.Empty())
            features = hw_to_dataset_features(robot, "observation")
            specs = RemotePolicyConfig("snapflow_groot", str(folder), features, 4, "cpu")
            stub.SendPolicyInstructions(services_pb2.PolicySetup(data=pickle.dumps(specs)))
            raw = {joint: 0.0 for joint in JOINTS} | {"task": "pick up the black bowl"}
            raw |= {camera: np.zeros((IMAGE_SIZE, IMAGE_SIZE, 3), np.uint8) for camera in ("image", "image2")}
            observation = TimedObservation(timestamp=time.time(), observation=raw, timestep=0, must_go=True)
            stub.SendObservations(send_bytes_in_chunks(pickle.dumps(observation), services_pb2.Observation))
            return pickle.loads(stub.GetActions(services_pb2.Empty()).data)  # nosec - our own server's answer
    finally:
        server.stop(0)


@pytest.mark.slow
@pytest.mark.lerobot
def test_the_writers_groot_is_distilled_stepped_served_and_evaluated_as_a_user_types_it(tmp_path, monkeypatch):
    work = tmp_path / "work"
    work.mkdir()
    _snapflow("collect", "--env", "libero-lod", "--tasks", "libero_spatial_0", "--episodes", "2", "--image-size",
              str(IMAGE_SIZE), "--output", "demos", "--lerobot-dataset", "data", "--threads", "1", cwd=work)  # fmt: skip
    writer = [sys.executable, "-m", "snapflow.adapters.lerobot.groot_checkpoint", "base", "--size", "tiny"]
    written = run_checked([*writer, "--dataset", "data"], {"HF_HUB_OFFLINE": "1"}, cwd=work).stdout.strip()
    assert Path(written) == work / "base" / "lerobot_policy"
    _snapflow("distill", "--policy", "base/lerobot_policy", "--lerobot-train", "--output", "student", cwd=work)
    assert json.loads((work / "student" / "config.json").read_text())["type"] == "snapflow_groot"

    monkeypatch.chdir(work)  # lerobot-train's run folder, as a user gives it: relative
    checkpoint = run_tiny_lerobot_train(Path("student"), Path("data"), Path("run"), 2, 2, "--log_freq=1")
    assert json.loads((checkpoint / "config.json").read_text())["distilled"] is True

    actions = _one_chunk(work / checkpoint)
    assert [action.get_timestep() for action in actions] == [0, 1, 2, 3]
    assert all(
        action.get_action().shape == (7,) and np.isfinite(action.get_action().numpy()).all() for action in actions
    )

    _snapflow("eval", "--policy", str(checkpoint), "--lerobot-env", "libero", "--env-task", "libero_spatial_0",
              "--episodes", "1", "--max-episode-steps", "8", "--modes", "snapflow-1,teacher", "--output", "eval",
              "--threads", "1", cwd=work)  # fmt: skip
    report = json.loads((work / "eval" / "report.json").read_text())
    assert {name: mode["nfe"] for name, mode in report["modes"].items()} == {"snapflow-1": 1, "teacher-4": 4}
