"""``snapflow serve`` started as a user starts it: a command in its own process, which must register the student types
itself, and a client written from LeRobot's own gRPC types. Payloads that would run code in the server (here: create a
file) are refused by name, before they run, and the server goes on to serve a student."""

from __future__ import annotations

import contextlib
import datetime
import ipaddress
import json
import os
import pickle
import shutil
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest

pytest.importorskip("lerobot", reason="LeRobot is installed by the README's test command; this environment lacks it")
from snapflow.adapters.lerobot_types import PLUGIN_LEROBOT, lerobot_loads_plugins  # noqa: E402

if not lerobot_loads_plugins():
    pytest.skip(f"snapflow serve needs lerobot {PLUGIN_LEROBOT} or newer", allow_module_level=True)
grpc = pytest.importorskip("grpc", reason="LeRobot's async extra (lerobot[async]) brings grpcio")

from lerobot.async_inference.helpers import RemotePolicyConfig, TimedObservation  # noqa: E402
from lerobot.transport import services_pb2, services_pb2_grpc  # noqa: E402
from lerobot.transport.utils import send_bytes_in_chunks  # noqa: E402
from lerobot.utils.feature_utils import hw_to_dataset_features  # noqa: E402

from tests.helpers import free_loopback_port  # noqa: E402
from tests.lerobot_tiny import IMAGE_SIZE, save_tiny_student  # noqa: E402

JOINTS = ("shoulder.pos", "elbow.pos", "wrist.pos", "wrist_roll.pos")


class CreatesAFile:
    """What an attacker sends: unpickling it calls ``open(path, "w")``, which creates the file."""

    def __init__(self, path: Path) -> None:
        self.path = path

    def __reduce__(self):
        return open, (str(self.path), "w")


def serve_command(port: int) -> list[str]:
    return [str(Path(sys.executable).with_name("snapflow")), "serve", "--host", "127.0.0.1", "--port", str(port)]


@contextlib.contextmanager
def running_server(folder: Path, *options: str, channel: Callable[[str], Any] = grpc.insecure_channel):
    """``snapflow serve OPTIONS`` on a free loopback port, in a process of its own started in ``folder``, its
    LeRobot log in ``folder/server-logs``; its port once it answers on a channel made by ``channel``."""
    port = free_loopback_port()
    process = subprocess.Popen(
        [*serve_command(port), *options],
        cwd=folder,
        env={**os.environ, "SNAPFLOW_SERVE_LOGS": str(folder / "server-logs")},
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        stdin=subprocess.DEVNULL,
        text=True,
    )
    try:
        with channel(f"127.0.0.1:{port}") as ready:
            grpc.channel_ready_future(ready).result(timeout=120)
        yield port
    finally:
        process.terminate()
        output, _ = process.communicate(timeout=30)
        print(output)  # shown on a failure: what the server logged


@pytest.fixture
def server(tmp_path):
    with running_server(tmp_path, "--inference-latency", "0") as port:
        yield port


def _kept_student(vlm_directory: Path, folder: Path) -> Path:
    """A tiny distilled SmolVLA whose SmolVLM lives inside its folder, named relative to it, as a kept one's."""
    from snapflow.adapters.lerobot.local_vlm import BUNDLED_VLM, bundle_vlm

    save_tiny_student(vlm_directory, folder, image_key="observation.images.front", image_size=IMAGE_SIZE)
    assert bundle_vlm(folder) and json.loads((folder / "config.json").read_text())["vlm_model_name"] == BUNDLED_VLM
    return folder


def _files(folder: Path) -> dict[str, int]:
    return {str(path.relative_to(folder)): path.stat().st_mtime_ns for path in sorted(folder.rglob("*"))}


@pytest.mark.slow
def test_the_command_serves_a_student_and_refuses_a_payload_that_runs_code(server, vlm_directory, tmp_path):
    """Started outside the policy folder, the server serves a kept student named by a path relative to its working
    directory, writes nothing into the folder, and tells the client why it refuses a student never distilled, a
    folder that is not there and a payload that runs code; a second server on its port is refused."""
    student = _kept_student(vlm_directory, tmp_path / "policies" / "student")
    untouched = _files(student.parent)
    robot = {**dict.fromkeys(JOINTS, float), "front": (IMAGE_SIZE, IMAGE_SIZE, 3)}
    features = hw_to_dataset_features(robot, "observation")
    marker = tmp_path / "created-by-a-client"
    with grpc.insecure_channel(f"127.0.0.1:{server}") as channel:
        stub = services_pb2_grpc.AsyncInferenceStub(channel)
        stub.Ready(services_pb2.Empty())
        payload = pickle.dumps(CreatesAFile(marker))
        with pytest.raises(grpc.RpcError) as refused:
            stub.SendPolicyInstructions(services_pb2.PolicySetup(data=payload))
        assert refused.value.code() == grpc.StatusCode.INVALID_ARGUMENT
        assert "refused a message that calls _io.open" in refused.value.details()
        with pytest.raises(grpc.RpcError, match="refused a message that calls _io.open"):
            stub.SendObservations(send_bytes_in_chunks(payload, services_pb2.Observation))
        assert not marker.exists(), "the client's code ran in the server"

        # refusals the client reads: a student never distilled, a folder that is not there, a type not served
        never = shutil.copytree(student, tmp_path / "policies" / "never-distilled")
        config = json.loads((never / "config.json").read_text())
        (never / "config.json").write_text(json.dumps({**config, "distilled": False}))
        for policy_type, folder, status, reason in (
            ("snapflow_smolvla", never, grpc.StatusCode.FAILED_PRECONDITION, "was not distilled"),
            ("snapflow_smolvla", tmp_path / "nowhere", grpc.StatusCode.NOT_FOUND, "nowhere"),
            ("no_such_type", student, grpc.StatusCode.INVALID_ARGUMENT, "'no_such_type' is not served"),
        ):
            specs = RemotePolicyConfig(policy_type, str(folder), features, 4, "cpu")
            with pytest.raises(grpc.RpcError) as refused:
                stub.SendPolicyInstructions(services_pb2.PolicySetup(data=pickle.dumps(specs)))
            assert refused.value.code() == status and reason in refused.value.details(), refused.value.details()

        # the same server, on: a student of the plugin's type (which the command registered itself), by a path
        # relative to the server's working directory, its SmolVLM inside its folder
        specs = RemotePolicyConfig("snapflow_smolvla", "policies/student", features, 4, "cpu")
        stub.SendPolicyInstructions(services_pb2.PolicySetup(data=pickle.dumps(specs)))
        raw = {joint: 0.1 * index for index, joint in enumerate(JOINTS)}
        raw |= {"front": np.zeros((IMAGE_SIZE, IMAGE_SIZE, 3), np.uint8), "task": "reach the red block"}
        observation = TimedObservation(timestamp=time.time(), observation=raw, timestep=0, must_go=True)
        stub.SendObservations(send_bytes_in_chunks(pickle.dumps(observation), services_pb2.Observation))
        actions = pickle.loads(stub.GetActions(services_pb2.Empty()).data)  # nosec - the answer of our own server
    assert [action.get_timestep() for action in actions] == [0, 1, 2, 3]
    assert all(np.isfinite(action.get_action().numpy()).all() for action in actions)
    assert {name: time for name, time in _files(student.parent).items() if name in untouched} == untouched
    assert not (student / "logs").exists() and (tmp_path / "server-logs" / "logs").is_dir()

    # a second server on the port is refused, by name, and exits: it would have listened beside the first
    second = subprocess.run(
        serve_command(server), cwd=tmp_path, capture_output=True, text=True, timeout=300, stdin=subprocess.DEVNULL
    )
    assert second.returncode == 2, second.stdout + second.stderr
    assert f"cannot listen on 127.0.0.1:{server}: the port is in use" in second.stderr
    assert "Traceback" not in second.stderr and "serving" not in second.stdout


@pytest.mark.slow
def test_the_round_trip_benchmark_times_both_modes_under_the_floor_and_without_it(tmp_path):
    """``scripts/serve_round_trip.py`` in its short form: the committed table's four rows, each timed."""
    script = Path(__file__).resolve().parents[2] / "scripts" / "serve_round_trip.py"
    arguments = [sys.executable, str(script), str(tmp_path), "--chunks", "2", "--warmup", "1"]
    finished = subprocess.run(arguments, capture_output=True, text=True, timeout=600, env=os.environ)
    assert finished.returncode == 0, finished.stderr[-3000:]
    result = json.loads((tmp_path / "round_trip.json").read_text())
    assert [(row["floor_s"], row["mode"]) for row in result["rows"]] == [
        (None, "snapflow-1"),
        (None, "teacher-10"),
        (0.0, "snapflow-1"),
        (0.0, "teacher-10"),
    ]
    assert all(row["chunks"] == 2 and 0 < row["median_ms"] <= row["p90_ms"] for row in result["rows"])
    assert "| 0 s | snapflow-1 |" in (tmp_path / "round_trip.md").read_text()


def _certificate(name: str, key: Any, issuer: tuple[Any, str] | None = None, ip: str | None = None) -> Any:
    """An X.509 certificate of ``name`` for ``key``, signed by ``issuer`` (its key and name), else by itself (a CA);
    valid for ``ip`` where given."""
    from cryptography import x509
    from cryptography.hazmat.primitives import hashes
    from cryptography.x509.oid import NameOID

    signer, issuer_name = issuer or (key, name)
    now = datetime.datetime.now(datetime.UTC)
    builder = (
        x509.CertificateBuilder()
        .subject_name(x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, name)]))
        .issuer_name(x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, issuer_name)]))
        .public_key(key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(now - datetime.timedelta(minutes=5))
        .not_valid_after(now + datetime.timedelta(days=1))
        .add_extension(x509.BasicConstraints(ca=issuer is None, path_length=None), critical=True)
    )
    if ip:
        builder = builder.add_extension(x509.SubjectAlternativeName([x509.IPAddress(ipaddress.ip_address(ip))]), False)
    return builder.sign(signer, hashes.SHA256())


def _write_mutual_tls(folder: Path) -> dict[str, Path]:
    """A CA, a server certificate for 127.0.0.1 and a client certificate, both signed by the CA, as PEM files."""
    from cryptography.hazmat.primitives import serialization
    from cryptography.hazmat.primitives.asymmetric import ec

    def pem_key(key: Any) -> bytes:
        return key.private_bytes(
            serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8, serialization.NoEncryption()
        )

    keys = {name: ec.generate_private_key(ec.SECP256R1()) for name in ("ca", "server", "client")}
    certificates = {
        "ca": _certificate("snapflow test CA", keys["ca"]),
        "server": _certificate("127.0.0.1", keys["server"], (keys["ca"], "snapflow test CA"), ip="127.0.0.1"),
        "client": _certificate("robot", keys["client"], (keys["ca"], "snapflow test CA")),
    }
    files = {}
    for name, certificate in certificates.items():
        files[f"{name}.pem"] = folder / f"{name}.pem"
        files[f"{name}.pem"].write_bytes(certificate.public_bytes(serialization.Encoding.PEM))
        files[f"{name}-key.pem"] = folder / f"{name}-key.pem"
        files[f"{name}-key.pem"].write_bytes(pem_key(keys[name]))
    return files


@pytest.mark.slow
def test_over_mutual_tls_only_a_client_with_a_certificate_of_the_ca_is_served(tmp_path):
    files = _write_mutual_tls(tmp_path)
    ca = files["ca.pem"].read_bytes()
    with_certificate = grpc.ssl_channel_credentials(
        ca, files["client-key.pem"].read_bytes(), files["client.pem"].read_bytes()
    )
    options = ["--tls-cert", str(files["server.pem"]), "--tls-key", str(files["server-key.pem"])]
    options += ["--tls-client-ca", str(files["ca.pem"])]

    def secure(address: str) -> Any:
        return grpc.secure_channel(address, with_certificate)

    with running_server(tmp_path, *options, channel=secure) as port:
        address = f"127.0.0.1:{port}"
        with grpc.secure_channel(address, with_certificate) as channel:
            services_pb2_grpc.AsyncInferenceStub(channel).Ready(services_pb2.Empty(), timeout=30)
        # no client certificate, or no TLS at all (LeRobot's own client): the handshake fails, nothing is served
        for refused in (grpc.secure_channel(address, grpc.ssl_channel_credentials(ca)), grpc.insecure_channel(address)):
            with refused as channel, pytest.raises(grpc.RpcError) as failed:
                services_pb2_grpc.AsyncInferenceStub(channel).Ready(services_pb2.Empty(), timeout=10)
            assert failed.value.code() == grpc.StatusCode.UNAVAILABLE
