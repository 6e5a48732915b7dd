"""``snapflow serve``: LeRobot's own async-inference policy server serves a distilled student (SmolVLA, pi0, pi0.5,
X-VLA, multi-task DiT, GR00T N1.7, EVO1, EO-1, VLA-JEPA, MolmoAct2) to a client made of LeRobot's own gRPC types,
one denoising pass a chunk (ten as its teacher), and refuses the student asked for under its teacher's type instead
of dropping phi_s. LeRobot's server calls ``predict_action_chunk`` on its own, where a multi-task DiT reads observation queues only its
``select_action`` fills (LeRobot 0.6.1, a teacher fails there): its student fills them from the observation it is
given."""

from __future__ import annotations

import pickle
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("lerobot", reason="LeRobot is installed by the README's test command; this environment lacks it")
from snapflow.adapters.lerobot_types import PLUGIN_LEROBOT, lerobot_loads_plugins  # noqa: E402

if not lerobot_loads_plugins():
    pytest.skip(
        f"LeRobot's tools load third-party policy types from lerobot {PLUGIN_LEROBOT} on", allow_module_level=True
    )
grpc = pytest.importorskip("grpc", reason="LeRobot's async extra (lerobot[async]) brings grpcio")

from lerobot.async_inference.configs import PolicyServerConfig  # noqa: E402
from lerobot.async_inference.helpers import RemotePolicyConfig, TimedObservation  # noqa: E402
from lerobot.transport import services_pb2, services_pb2_grpc  # noqa: E402
from lerobot.transport.utils import send_bytes_in_chunks  # noqa: E402
from lerobot.utils.feature_utils import hw_to_dataset_features  # noqa: E402

from snapflow.adapters.lerobot.serve import start_server  # noqa: E402
from tests.helpers import free_loopback_port  # noqa: E402
from tests.lerobot_tiny import (  # noqa: E402
    IMAGE_SIZE,
    PI_IMAGE_SIZE,
    save_tiny_pi_student,
    save_tiny_student,
    tiny_pi_configs,
)
from tests.lerobot_tiny_eo1 import EO1_IMAGE_SIZE, save_tiny_eo1_student  # noqa: E402
from tests.lerobot_tiny_evo1 import save_tiny_evo1_student  # noqa: E402
from tests.lerobot_tiny_groot import GROOT_IMAGE_SIZE, save_tiny_groot_student  # noqa: E402
from tests.lerobot_tiny_molmoact2 import save_tiny_molmoact2_student  # noqa: E402
from tests.lerobot_tiny_multi_task_dit import save_tiny_multi_task_dit_student  # noqa: E402
from tests.lerobot_tiny_vla_jepa import VLA_JEPA_IMAGE_SIZE, save_tiny_vla_jepa_student  # noqa: E402
from tests.lerobot_tiny_xvla import save_tiny_xvla_student  # noqa: E402

JOINTS = ("shoulder.pos", "elbow.pos", "wrist.pos", "wrist_roll.pos", "forearm.pos", "gripper.pos")


@dataclass(frozen=True)
class Served:
    """A saved tiny student and what a robot client sends it: one motor per state dimension and one camera."""

    base_type: str
    folder: Path
    joints: tuple[str, ...]
    camera: str
    image_size: int

    @property
    def features(self) -> dict:
        robot = {**dict.fromkeys(self.joints, float), self.camera: (self.image_size, self.image_size, 3)}
        return hw_to_dataset_features(robot, "observation")


@pytest.fixture(
    scope="module",
    params=["smolvla", "pi0", "pi05", "xvla", "multi_task_dit", "groot", "evo1", "eo1", "vla_jepa", "molmoact2"],
)
def student(request, vlm_directory, tmp_path_factory):
    folder = tmp_path_factory.mktemp("serve") / request.param
    if request.param == "groot":  # a 6-D state, one top camera, its backbone a tiny Qwen3-VL
        save_tiny_groot_student(request.getfixturevalue("groot_checkpoint"), folder)
        yield Served("groot", folder, JOINTS, "top", GROOT_IMAGE_SIZE)
        return
    if request.param == "evo1":  # a 6-D state, one 32-pixel top camera, its VLM a tiny InternVL3 with weights
        save_tiny_evo1_student(request.getfixturevalue("evo1_vlm"), folder)
        yield Served("evo1", folder, JOINTS, "top", 32)
        return
    if request.param == "eo1":  # a 6-D state, one 64-pixel top camera, its VLM a tiny Qwen2.5-VL with weights
        save_tiny_eo1_student(request.getfixturevalue("eo1_vlm"), folder)
        yield Served("eo1", folder, JOINTS, "top", EO1_IMAGE_SIZE)
        return
    if request.param == "vla_jepa":  # a 6-D state, one 32-pixel top camera, a tiny Qwen3-VL and V-JEPA 2 with weights
        save_tiny_vla_jepa_student(request.getfixturevalue("vla_jepa_backbones"), folder)
        yield Served("vla_jepa", folder, JOINTS, "top", VLA_JEPA_IMAGE_SIZE)
        return
    if request.param == "molmoact2":  # a 6-D state, one 32-pixel top camera, its checkpoint a tiny MolmoAct2
        save_tiny_molmoact2_student(request.getfixturevalue("molmoact2_checkpoint"), folder)
        yield Served("molmoact2", folder, JOINTS, "top", 32)
        return
    if request.param == "multi_task_dit":  # a 6-D state, one top camera, its encoders a tiny CLIP
        clip = request.getfixturevalue("clip_directory")
        save_tiny_multi_task_dit_student(clip, folder)
        yield Served("multi_task_dit", folder, JOINTS, "top", IMAGE_SIZE)
        return
    if request.param == "smolvla":  # a 4-D state, one front camera
        save_tiny_student(vlm_directory, folder, image_key="observation.images.front", image_size=IMAGE_SIZE)
        yield Served("smolvla", folder, JOINTS[:4], "front", IMAGE_SIZE)
        return
    if request.param == "xvla":  # a 6-D state, one top camera
        save_tiny_xvla_student(vlm_directory, folder)
        yield Served("xvla", folder, JOINTS, "top", IMAGE_SIZE)
        return
    save_tiny_pi_student(request.param, vlm_directory, folder)  # a 6-D state, one top camera
    with tiny_pi_configs(request.param):  # the server loads it in this process
        yield Served(request.param, folder, JOINTS, "top", PI_IMAGE_SIZE)


def _chunk(stub, policy_server, student: Served, sampling_mode: str, actions_per_chunk: int = 4) -> tuple[list, int]:
    """What LeRobot's robot client does, with its own types: policy instructions, one observation, one chunk back;
    and how many denoising passes the server's policy ran for it."""
    config = student.folder / "config.json"
    config.write_text(
        config.read_text().replace('"snapflow-1"', f'"{sampling_mode}"').replace('"teacher-10"', f'"{sampling_mode}"')
    )
    specs = RemotePolicyConfig(
        f"snapflow_{student.base_type}", str(student.folder), student.features, actions_per_chunk, "cpu"
    )
    stub.SendPolicyInstructions(services_pb2.PolicySetup(data=pickle.dumps(specs)))
    adapter, calls = policy_server.policy.snapflow, []  # every type's velocity goes through its adapter's denoise
    denoise = adapter.denoise
    adapter.denoise = lambda *args, **kwargs: calls.append(1) or denoise(*args, **kwargs)
    raw = {joint: 0.1 * index for index, joint in enumerate(student.joints)}
    raw |= {student.camera: np.zeros((student.image_size,) * 2 + (3,), np.uint8), "task": "reach the red block"}
    observation = TimedObservation(timestamp=time.time(), observation=raw, timestep=0, must_go=True)
    stub.SendObservations(send_bytes_in_chunks(pickle.dumps(observation), services_pb2.Observation))
    actions = pickle.loads(stub.GetActions(services_pb2.Empty()).data)  # nosec - our own server's answer
    return actions, len(calls)


@pytest.mark.slow
def test_lerobots_policy_server_serves_a_student_one_pass_a_chunk(student):
    port = free_loopback_port()
    server, policy_server = start_server(PolicyServerConfig(host="127.0.0.1", port=port, inference_latency=0.0))
    try:
        with grpc.insecure_channel(f"127.0.0.1:{port}") as channel:
            stub = services_pb2_grpc.AsyncInferenceStub(channel)
            stub.Ready(services_pb2.Empty())
            for mode, passes in (("snapflow-1", 1), ("teacher-10", 10)):
                actions, counted = _chunk(stub, policy_server, student, mode)
                assert counted == passes, mode
                assert len(actions) == 4 and all(np.isfinite(a.get_action().numpy()).all() for a in actions)
                assert [a.get_timestep() for a in actions] == [0, 1, 2, 3]
    finally:
        server.stop(0)


def test_a_student_asked_for_under_its_teachers_type_is_refused_by_name(student):
    port = free_loopback_port()
    server, _ = start_server(PolicyServerConfig(host="127.0.0.1", port=port))
    try:
        with grpc.insecure_channel(f"127.0.0.1:{port}") as channel:
            stub = services_pb2_grpc.AsyncInferenceStub(channel)
            stub.Ready(services_pb2.Empty())
            specs = RemotePolicyConfig(student.base_type, str(student.folder), student.features, 4, "cpu")
            with pytest.raises(grpc.RpcError, match=f"holds a SnapFlow student distilled from {student.base_type}"):
                stub.SendPolicyInstructions(services_pb2.PolicySetup(data=pickle.dumps(specs)))
    finally:
        server.stop(0)
