"""``snapflow collect``: expert demonstrations of a benchmark, also as a LeRobotDataset."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from snapflow.cli.common import COUNT, TASKS_HELP, add_command, add_output, check_writable, tasks
from snapflow.data.collect import EPISODES_PER_TASK
from snapflow.envs.factory import BENCHMARKS, DEFAULT_BENCHMARK, make_benchmark


def add_parser(subparsers: Any) -> None:
    parser = add_command(subparsers, "collect", "expert demonstrations (successful episodes only)", run, _interrupted)
    parser.add_argument(
        "--env",
        choices=list(BENCHMARKS),
        default=DEFAULT_BENCHMARK,
        help="benchmark; metaworld-via-points routes each episode through one of two via-points (multimodal)",
    )
    parser.add_argument("--tasks", help=TASKS_HELP)
    parser.add_argument("--episodes", type=COUNT, default=EPISODES_PER_TASK, help="successful episodes per task")
    parser.add_argument(
        "--image-size",
        type=COUNT,
        help="also store camera images of this size (rendered off-screen with MUJOCO_GL=egl or osmesa)",
    )
    add_output(parser, None, "demonstrations directory (npz + meta.json)")
    parser.add_argument(
        "--lerobot-dataset",
        metavar="ROOT",
        help="also write them as a LeRobotDataset at this (new) root, with LeRobot's writer (needs snapflow-vla[lerobot])",
    )
    parser.add_argument("--repo-id", help="the LeRobotDataset's repo id (default: local/<ROOT's folder name>)")


def run(args: argparse.Namespace) -> int:
    chosen = tasks(args.env, args.tasks)
    check_writable(args.output)
    benchmark = make_benchmark(args.env)
    if args.lerobot_dataset:  # LeRobot's import and the root are checked before any episode runs
        from snapflow.adapters.lerobot.dataset import check_dataset_root, write_lerobot_dataset

        check_dataset_root(args.lerobot_dataset)
    from snapflow.data.collect import collect

    progress = not args.no_progress
    demonstrations = collect(benchmark, chosen, args.episodes, args.output, args.image_size, progress)
    if args.lerobot_dataset:
        write_lerobot_dataset(
            demonstrations, args.lerobot_dataset, args.repo_id, benchmark.fps, benchmark.camera, progress
        )
    also = f" and as a LeRobotDataset to {args.lerobot_dataset}" if args.lerobot_dataset else ""
    print(
        f"wrote {len(demonstrations.episodes)} successful expert episodes ({len(demonstrations.states)} steps) "
        f"to {args.output}{also}"
    )
    return 0


def _interrupted(args: argparse.Namespace) -> str:
    from snapflow.data.demonstrations import META_FILE

    if args.lerobot_dataset and (Path(args.output) / META_FILE).is_file():
        return f"interrupted; the demonstrations are saved in {args.output}, no LeRobotDataset was written"
    return f"interrupted; no demonstrations were saved in {args.output}"
