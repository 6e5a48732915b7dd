"""The round trip of a chunk through ``snapflow serve``, as LeRobot's robot client sees it, for a distilled SmolVLA
student in both modes (``snapflow-1``, ``teacher-10``), under LeRobot's latency floor and without it.

    python scripts/serve_round_trip.py OUTPUT [--size tiny|small] [--chunks 40] [--warmup 5]

It builds a SmolVLA over a SmolVLM written locally at ``--size`` (random weights: a chunk's cost does not depend on
them), saves it as a distilled student, starts ``snapflow serve`` as a command for each floor, and then does what
LeRobot's robot client does with LeRobot's own gRPC types: policy instructions, then per chunk one observation and
``GetActions``, timed from sending the observation to the chunk back. Medians after warm-up, one server at a time on
the loopback; ``OUTPUT/round_trip.json`` and ``round_trip.md``. Needs lerobot >= 0.5 (``snapflow serve``).
"""

from __future__ import annotations

import argparse
import json
import os
import pickle
import platform
import socket
import statistics
import subprocess
import sys
import tempfile
import time
from importlib.metadata import version
from pathlib import Path

import numpy as np
import torch

from snapflow.adapters.lerobot_config import SMOLVLM_SIZES
from snapflow.reporting.files import write_json, write_text
from snapflow.reporting.tables import markdown_table

JOINTS = ("shoulder.pos", "elbow.pos", "wrist.pos", "wrist_roll.pos", "forearm.pos", "gripper.pos")
MODES = ("snapflow-1", "teacher-10")
FLOORS = (None, 0.0)  # LeRobot's default (1/30 s), then none


def save_student(folder: Path, size: str) -> tuple[Path, dict]:
    """A random SmolVLA student of ``size`` saved as distilled, with unit-statistics processors; its features as the
    robot client declares them."""
    from lerobot.configs.types import FeatureType, PolicyFeature
    from lerobot.policies.factory import make_pre_post_processors
    from lerobot.policies.smolvla.modeling_smolvla import SmolVLAPolicy
    from lerobot.utils.feature_utils import hw_to_dataset_features

    from snapflow.adapters.lerobot import save_distilled, wrap_policy
    from snapflow.adapters.lerobot.smolvlm import smolvla_config, write_smolvlm

    dimensions = SMOLVLM_SIZES[size]
    image = dimensions.image_size
    vlm = write_smolvlm(folder / "smolvlm", ["reach", "the", "red", "block"], dimensions)
    inputs = {
        "observation.state": PolicyFeature(FeatureType.STATE, (len(JOINTS),)),
        "observation.images.front": PolicyFeature(FeatureType.VISUAL, (3, image, image)),
    }
    outputs = {"action": PolicyFeature(FeatureType.ACTION, (len(JOINTS),))}
    policy = SmolVLAPolicy(smolvla_config(vlm, inputs, outputs, dimensions))
    student = save_distilled(wrap_policy(policy), folder / "student")
    stats = {
        key: {"mean": torch.zeros(len(JOINTS)), "std": torch.ones(len(JOINTS))}
        for key in ("observation.state", "action")
    }
    for processor in make_pre_post_processors(policy.config, dataset_stats=stats):
        processor.save_pretrained(student)
    robot = {**dict.fromkeys(JOINTS, float), "front": (image, image, 3)}
    return student, {"features": hw_to_dataset_features(robot, "observation"), "image_size": image}


def free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


def time_chunks(port: int, student: Path, described: dict, mode: str, chunks: int, warmup: int) -> list[float]:
    """Milliseconds from each observation sent to its chunk back, after ``warmup`` chunks, for ``mode``."""
    import grpc
    from lerobot.async_inference.helpers import RemotePolicyConfig, TimedObservation
    from lerobot.transport import services_pb2, services_pb2_grpc
    from lerobot.transport.utils import send_bytes_in_chunks

    config = json.loads((student / "config.json").read_text())
    (student / "config.json").write_text(json.dumps({**config, "sampling_mode": mode}))
    image = described["image_size"]
    timings = []
    with grpc.insecure_channel(f"127.0.0.1:{port}") as channel:
        stub = services_pb2_grpc.AsyncInferenceStub(channel)
        stub.Ready(services_pb2.Empty())
        specs = RemotePolicyConfig("snapflow_smolvla", str(student), described["features"], 10, "cpu")
        stub.SendPolicyInstructions(services_pb2.PolicySetup(data=pickle.dumps(specs)))
        for step in range(warmup + chunks):
            raw = {joint: 0.01 * step for joint in JOINTS}
            raw |= {"front": np.full((image, image, 3), step % 255, np.uint8), "task": "reach the red block"}
            observation = TimedObservation(timestamp=time.time(), observation=raw, timestep=step, must_go=True)
            started = time.perf_counter()
            stub.SendObservations(send_bytes_in_chunks(pickle.dumps(observation), services_pb2.Observation))
            answer = stub.GetActions(services_pb2.Empty())
            elapsed = 1000 * (time.perf_counter() - started)
            if not answer.data:
                raise RuntimeError(f"the server sent no chunk for observation {step}")
            if step >= warmup:
                timings.append(elapsed)
    return timings


def serve(port: int, floor: float | None, folder: Path) -> subprocess.Popen:
    command = [str(Path(sys.executable).with_name("snapflow")), "serve", "--host", "127.0.0.1", "--port", str(port)]
    command += [] if floor is None else ["--inference-latency", str(floor)]
    import grpc

    process = subprocess.Popen(command, cwd=folder, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    with grpc.insecure_channel(f"127.0.0.1:{port}") as channel:
        grpc.channel_ready_future(channel).result(timeout=120)
    return process


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("output", type=Path)
    parser.add_argument("--size", choices=list(SMOLVLM_SIZES), default="tiny")
    parser.add_argument("--chunks", type=int, default=40, help="chunks timed per mode and floor, after the warm-up")
    parser.add_argument("--warmup", type=int, default=5)
    args = parser.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as scratch:  # the student and the server's logs: nothing of them is kept
        work = Path(scratch)
        student, described = save_student(work, args.size)
        for floor in FLOORS:
            port = free_port()
            process = serve(port, floor, work)
            try:
                for mode in MODES:
                    timings = time_chunks(port, student, described, mode, args.chunks, args.warmup)
                    rows.append(
                        {
                            "floor_s": floor,
                            "mode": mode,
                            "median_ms": statistics.median(timings),
                            "p90_ms": float(np.percentile(timings, 90)),
                            "chunks": len(timings),
                        }
                    )
                    print(rows[-1], flush=True)
            finally:
                process.terminate()
                process.wait(timeout=30)
    result = {
        "size": args.size,
        "warmup": args.warmup,
        "rows": rows,
        "machine": f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores",
        "versions": {"python": platform.python_version(), "torch": torch.__version__, "lerobot": version("lerobot")},
    }
    write_json(args.output / "round_trip.json", result)
    table = markdown_table(
        ["LeRobot floor", "mode", "median ms", "p90 ms", "chunks"],
        [
            (
                "1/30 s (default)" if row["floor_s"] is None else f"{row['floor_s']:g} s",
                row["mode"],
                f"{row['median_ms']:.1f}",
                f"{row['p90_ms']:.1f}",
                row["chunks"],
            )
            for row in rows
        ],
    )
    write_text(args.output / "round_trip.md", table + "\n")
    print(table)


if __name__ == "__main__":
    main()
