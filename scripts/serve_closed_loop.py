"""A LeRobot policy served by ``snapflow serve`` and run in closed loop by a client of LeRobot's own gRPC types, on a
snapflow benchmark's episodes (LIBERO's fixed initial states, Meta-World's evaluation variations): success counted
and the round trip of every chunk timed, as a robot would meet the server.

    python scripts/serve_closed_loop.py --policy STUDENT --env libero --tasks libero_spatial --episodes 2 \\
        --output OUTPUT [--mode snapflow-1] [--n-action-steps 4] [--first-variation 0] [--max-episode-steps N]

It starts ``snapflow serve`` on the loopback as a command (LeRobot's latency floor off: each chunk comes back when it
is ready), sends the policy instructions, then for each episode resets the environment on its variation and, until
success or the task's step limit (or ``--max-episode-steps``, a quick check's cut), sends the observation as LeRobot's
robot client does (joint-like state entries, HWC uint8 frames, the instruction), takes the chunk's first
``--n-action-steps`` actions back (read through snapflow's allow-list unpickler) and executes them. The policy folder is served from a copy whose config names ``--mode``.
Writes ``OUTPUT/episodes.jsonl`` (one line an episode, as it ends), ``summary.json`` and ``summary.md``. Needs
lerobot >= 0.5 (``snapflow serve``).
"""

from __future__ import annotations

import argparse
import json
import pickle
import shutil
import socket
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from snapflow.envs.factory import BENCHMARKS, make_benchmark
from snapflow.reporting.files import write_json, write_text
from snapflow.reporting.machine import versions
from snapflow.reporting.statistics import wilson_interval
from snapflow.reporting.tables import markdown_table

STATE_NAME = "state_{}"  # the raw state entries the client sends, one a dimension, as a robot's joints are


def free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


def served_copy(policy: Path, mode: str, folder: Path) -> tuple[Path, dict]:
    """A copy of the policy folder whose config runs ``mode``; its config."""
    copy = shutil.copytree(policy, folder / "policy")
    config = json.loads((copy / "config.json").read_text())
    config["sampling_mode"] = mode
    (copy / "config.json").write_text(json.dumps(config, indent=2))
    return copy, config


def client_features(config: dict) -> tuple[dict, list[str], int, int]:
    """What the client declares (LeRobot's hardware features: the state's entries and the cameras' frames), the
    cameras in the policy's order, their side and the state's width."""
    from lerobot.utils.feature_utils import hw_to_dataset_features

    inputs = config["input_features"]
    cameras = [key.removeprefix("observation.images.") for key in inputs if key.startswith("observation.images.")]
    side = inputs[f"observation.images.{cameras[0]}"]["shape"][-1]
    state_dim = inputs["observation.state"]["shape"][0]
    hardware = {STATE_NAME.format(index): float for index in range(state_dim)}
    hardware |= {camera: (side, side, 3) for camera in cameras}
    return hw_to_dataset_features(hardware, "observation"), cameras, side, state_dim


def raw_observation(observation, cameras: list[str], state_dim: int) -> dict:
    """The benchmark's observation as a robot client sends it: the state's first ``state_dim`` entries (those the
    policy reads, as snapflow's evaluator gives them), the first camera the benchmark's main one."""
    raw = {STATE_NAME.format(index): float(value) for index, value in enumerate(observation.state[:state_dim])}
    raw[cameras[0]] = observation.image
    raw |= {camera: observation.extra_images[camera] for camera in cameras[1:]}
    raw["task"] = observation.instruction
    return raw


def start_server(port: int, folder: Path) -> subprocess.Popen:
    import grpc

    command = [str(Path(sys.executable).with_name("snapflow")), "serve", "--host", "127.0.0.1", "--port", str(port)]
    process = subprocess.Popen(
        [*command, "--inference-latency", "0"],
        cwd=folder,
        stdin=subprocess.DEVNULL,
        stdout=(folder / "server.log").open("w"),
        stderr=subprocess.STDOUT,
    )
    with grpc.insecure_channel(f"127.0.0.1:{port}") as channel:
        grpc.channel_ready_future(channel).result(timeout=180)
    return process


def run_episode(
    stub, environment, variation: int, cameras: list[str], state_dim: int, start_step: int, limit: int | None
) -> dict:
    """One episode in closed loop through the server, ended at success, the task's limit or after ``limit`` steps;
    its success, steps and each chunk's round trip (ms)."""
    from lerobot.async_inference.helpers import TimedObservation
    from lerobot.transport import services_pb2
    from lerobot.transport.utils import send_bytes_in_chunks

    from snapflow.adapters.lerobot.safe_pickle import loads

    observation = environment.reset(variation, render=True)
    round_trips, timestep, success, done = [], start_step, False, False
    while not (success or done):
        timed = TimedObservation(
            timestamp=time.time(),
            observation=raw_observation(observation, cameras, state_dim),
            timestep=timestep,
            must_go=True,
        )
        started = time.perf_counter()
        # pickled as LeRobot's robot client sends it; the server reads it through its allow-list
        stub.SendObservations(send_bytes_in_chunks(pickle.dumps(timed), services_pb2.Observation))
        answer = stub.GetActions(services_pb2.Empty())
        round_trips.append(1000 * (time.perf_counter() - started))
        if not answer.data:
            raise RuntimeError(f"the server sent no chunk for timestep {timestep}")
        chunk = loads(answer.data)
        for index, action in enumerate(chunk):
            last = index == len(chunk) - 1
            observation, success, done = environment.step(action.get_action().numpy(), render=last)
            timestep += 1
            done = done or environment.steps == limit
            if success or done:
                break
    return {"success": bool(success), "steps": environment.steps, "round_trip_ms": round_trips, "timestep": timestep}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--policy", type=Path, required=True, help="a LeRobot student folder (config.json, weights)")
    parser.add_argument("--env", choices=list(BENCHMARKS), default="libero")
    parser.add_argument("--tasks", default=None, help="tasks or a task set (default: the benchmark's default set)")
    parser.add_argument("--episodes", type=int, default=2, help="episodes per task, on consecutive variations")
    parser.add_argument("--first-variation", type=int, default=0)
    parser.add_argument("--mode", default="snapflow-1", help="the sampling mode the server runs")
    parser.add_argument("--n-action-steps", type=int, default=4, help="actions executed per chunk")
    parser.add_argument("--max-episode-steps", type=int, default=None, help="end each episode there (a quick check)")
    parser.add_argument("--output", type=Path, required=True)
    args = parser.parse_args()
    if args.max_episode_steps is not None and args.max_episode_steps < 1:
        parser.error(f"--max-episode-steps must be at least 1, got {args.max_episode_steps}")

    import grpc
    from lerobot.async_inference.helpers import RemotePolicyConfig
    from lerobot.transport import services_pb2, services_pb2_grpc

    benchmark = make_benchmark(args.env)
    tasks = benchmark.resolve_tasks(args.tasks) if args.tasks else list(benchmark.default_tasks)
    args.output.mkdir(parents=True, exist_ok=True)
    log = args.output / "episodes.jsonl"
    log.write_text("")
    episodes = []
    with tempfile.TemporaryDirectory() as scratch:
        folder = Path(scratch)
        policy, config = served_copy(args.policy, args.mode, folder)
        features, cameras, side, state_dim = client_features(config)
        port = free_port()
        server = start_server(port, folder)
        try:
            with grpc.insecure_channel(f"127.0.0.1:{port}") as channel:
                stub = services_pb2_grpc.AsyncInferenceStub(channel)
                stub.Ready(services_pb2.Empty())
                specs = RemotePolicyConfig(config["type"], str(policy), features, args.n_action_steps, "cpu")
                stub.SendPolicyInstructions(services_pb2.PolicySetup(data=pickle.dumps(specs)))
                timestep = 0
                for task in tasks:
                    environment = benchmark.make_env(task, "eval", side, cameras[1:])
                    try:
                        for variation in range(args.first_variation, args.first_variation + args.episodes):
                            episode = run_episode(
                                stub, environment, variation, cameras, state_dim, timestep, args.max_episode_steps
                            )
                            timestep = episode.pop("timestep")
                            episodes.append({"task": task, "variation": variation, **episode})
                            with log.open("a") as lines:
                                lines.write(json.dumps(episodes[-1]) + "\n")
                            print(task, variation, "success" if episode["success"] else "failure", flush=True)
                    finally:
                        environment.close()
        finally:
            server.terminate()
            server.wait(timeout=60)
            shutil.copy(folder / "server.log", args.output / "server.log")
    successes = sum(episode["success"] for episode in episodes)
    every = [trip for episode in episodes for trip in episode["round_trip_ms"]]
    trips = every[1:] or every  # the first chunk warms the server up
    low, high = wilson_interval(successes, len(episodes))
    summary = {
        "policy": str(args.policy),
        "mode": args.mode,
        "env": args.env,
        "tasks": tasks,
        "episodes_per_task": args.episodes,
        "first_variation": args.first_variation,
        "n_action_steps": args.n_action_steps,
        "max_episode_steps": args.max_episode_steps,
        "episodes": len(episodes),
        "successes": successes,
        "success_rate": successes / len(episodes),
        "success_interval_95": [low, high],
        "round_trip_ms": {
            "median": statistics.median(trips),
            "p90": float(np.percentile(trips, 90)),
            "chunks": len(trips),
        },
        "versions": versions(),
    }
    write_json(args.output / "summary.json", summary)
    table = markdown_table(
        ["mode", "episodes", "successes", "success %", "round trip ms (median)", "p90", "chunks"],
        [
            (
                args.mode,
                len(episodes),
                successes,
                f"{100 * summary['success_rate']:.1f} [{100 * low:.1f}, {100 * high:.1f}]",
                f"{summary['round_trip_ms']['median']:.1f}",
                f"{summary['round_trip_ms']['p90']:.1f}",
                len(trips),
            )
        ],
    )
    write_text(args.output / "summary.md", table + "\n")
    print(table)


if __name__ == "__main__":
    main()
