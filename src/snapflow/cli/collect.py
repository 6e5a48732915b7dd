"""``snapflow collect``: expert demonstrations of a benchmark, also as a LeRobotDataset."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from snapflow.cli.common import (
    COUNT,
    NON_NEGATIVE_COUNT,
    TASKS_HELP,
    add_command,
    add_output,
    check_writable,
    number,
    tasks,
)
from snapflow.data.collect import EPISODES_PER_TASK, PARTS
from snapflow.data.demonstrations import META_FILE, Demonstrations
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
    parser.add_argument(
        "--extra-cameras",
        type=_camera_names,
        metavar="NAMES",
        help="with --image-size, the benchmark's cameras besides the main one to store, comma-separated, '' for none "
        "(default: all; libero: image2, the wrist camera): each costs its rendering at every step",
    )
    parser.add_argument(
        "--action-noise",
        type=number(float, 0),
        default=0.0,
        metavar="STD",
        help="execute each expert action plus Gaussian noise of this standard deviation, recording the expert's own "
        "(DART): demonstrations of the way back to the expert's path",
    )
    parser.add_argument(
        "--noise-seed",
        type=NON_NEGATIVE_COUNT,
        default=0,
        help="with --action-noise, the seed of the noise (beside each task and reset's own): another seed, another "
        "set of demonstrations from the same resets",
    )
    parser.add_argument(
        "--first-variation",
        type=NON_NEGATIVE_COUNT,
        default=0,
        help="each task's expert starts on its training variations (resets) from this one on: another set of "
        "demonstrations beside one of the first variations (default: the first ones)",
    )
    add_output(parser, None, "demonstrations directory (npz + meta.json)")
    parser.add_argument(
        "--lerobot-dataset",
        metavar="ROOT",
        help="also write them as a LeRobotDataset at this (new) root, with LeRobot's writer (needs "
        "snapflow-vla[lerobot]); demonstrations of the same collection already in --output are written, not collected again",
    )
    parser.add_argument("--repo-id", help="the LeRobotDataset's repo id (default: local/<ROOT's folder name>)")


def run(args: argparse.Namespace) -> int:
    chosen = tasks(args.env, args.tasks)
    check_writable(args.output)
    benchmark = make_benchmark(args.env)
    cameras = benchmark.check_cameras(args.extra_cameras)
    if args.lerobot_dataset:  # LeRobot's import and the root are checked before any episode runs
        from snapflow.adapters.lerobot.dataset import check_dataset_root, write_lerobot_dataset

        check_dataset_root(args.lerobot_dataset)
    from snapflow.data.collect import collect

    progress = not args.no_progress
    collected = args.lerobot_dataset and (Path(args.output) / META_FILE).is_file()
    if collected:  # an export that did not finish, or the same demonstrations wanted as a LeRobotDataset
        demonstrations = Demonstrations.load(args.output)
        _check_same_collection(
            demonstrations,
            args.output,
            benchmark.name,
            chosen,
            args.episodes,
            args.image_size,
            cameras,
            args.action_noise,
            args.noise_seed,
            args.first_variation,
        )
    else:
        demonstrations = collect(
            benchmark,
            chosen,
            args.episodes,
            args.output,
            args.image_size,
            progress,
            cameras,
            args.action_noise,
            args.first_variation,
            args.noise_seed,
        )
    if args.lerobot_dataset:
        write_lerobot_dataset(
            demonstrations, args.lerobot_dataset, args.repo_id, benchmark.fps, benchmark.camera, progress
        )
    if collected:
        print(
            f"wrote the {len(demonstrations.episodes)} expert episodes in {args.output} as a LeRobotDataset to "
            f"{args.lerobot_dataset}"
        )
        return 0
    also = f" and as a LeRobotDataset to {args.lerobot_dataset}" if args.lerobot_dataset else ""
    print(
        f"wrote {len(demonstrations.episodes)} successful expert episodes ({len(demonstrations.states)} steps) "
        f"to {args.output}{also}"
    )
    return 0


def _check_same_collection(
    demonstrations: Demonstrations,
    output: str,
    env: str,
    tasks: list[str],
    episodes: int,
    image_size: int | None,
    extra_cameras: tuple[str, ...],
    action_noise: float,
    noise_seed: int,
    first_variation: int,
) -> None:
    """Refuse demonstrations in ``output`` that another collection made: writing them would not give what the
    command asks for."""
    size = demonstrations.images.shape[1] if demonstrations.images is not None else None
    per_task = {task: sum(e.task == task for e in demonstrations.episodes) for task in demonstrations.tasks}
    cameras = tuple(demonstrations.extra_images)
    found = (
        demonstrations.env,
        demonstrations.tasks,
        set(per_task.values()),
        size,
        cameras,
        demonstrations.action_noise,
        demonstrations.noise_seed,
        demonstrations.first_variation,
    )
    cameras_asked = extra_cameras if image_size else ()
    asked = (env, tasks, {episodes}, image_size, cameras_asked, action_noise, noise_seed, first_variation)
    if found != asked:
        other_cameras = f", other cameras {list(cameras)}" if cameras else ""
        noise = f", action noise {demonstrations.action_noise}" if demonstrations.action_noise else ""
        noise += f" seed {demonstrations.noise_seed}" if demonstrations.noise_seed else ""
        noise += f", from variation {demonstrations.first_variation}" if demonstrations.first_variation else ""
        raise FileExistsError(
            f"{output} already holds other demonstrations ({demonstrations.env}, {len(per_task)} tasks, "
            f"{sorted(set(per_task.values()))} episodes a task, images {size or 'none'}{other_cameras}{noise}); "
            "choose another --output"
        )


def _camera_names(value: str) -> tuple[str, ...]:
    return tuple(name.strip() for name in value.split(",") if name.strip())


def _interrupted(args: argparse.Namespace) -> str:
    if args.lerobot_dataset and (Path(args.output) / META_FILE).is_file():
        return (
            f"interrupted; the demonstrations are saved in {args.output}, no LeRobotDataset was written "
            "(the same command writes it from them)"
        )
    return (
        f"interrupted; each task finished so far is kept in {Path(args.output) / PARTS}: the same command collects "
        "the others and puts them together"
    )
