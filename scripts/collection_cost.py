"""Where a LIBERO demonstration's time goes: the scene's reset, the physics, the observation (the cameras' renders),
the expert.

Runs the scripted expert of each task given for a few episodes, as a sweep's collection runs it (64-px frames of both
cameras at every step, DART noise 0.1), with a timer around each part of ``LiberoEnv``, and writes the split per task
as ``collection_cost.json`` and ``collection_cost.md`` in the output folder. Measure on quiet cores: the figures are
wall time. ``python scripts/collection_cost.py OUTPUT [--tasks ...] [--episodes 3]``
"""

from __future__ import annotations

import argparse
import os
import time
from collections import defaultdict
from collections.abc import Callable
from pathlib import Path
from typing import Any

from snapflow.data.collect import expert_episode, noise_generator
from snapflow.envs.factory import make_benchmark
from snapflow.reporting.files import write_json, write_text
from snapflow.reporting.machine import machine, versions
from snapflow.reporting.tables import markdown_table

TASKS = ("libero_spatial_0", "libero_object_0", "libero_goal_0", "libero_10_0")
PARTS = ("reset", "physics", "observe", "expert", "other")


def timed(totals: dict[str, float], part: str, function: Callable[..., Any]) -> Callable[..., Any]:
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        began = time.perf_counter()
        try:
            return function(*args, **kwargs)
        finally:
            totals[part] += time.perf_counter() - began

    return wrapper


def measure(task: str, episodes: int, image_size: int, env_name: str = "libero") -> dict[str, Any]:
    """The mean seconds a demonstration of ``task`` spends in each part (the first episode, which builds caches, not
    counted)."""
    benchmark = make_benchmark(env_name)
    env, expert = benchmark.make_env(task, "train", image_size), benchmark.make_expert(task)
    totals: dict[str, float] = defaultdict(float)
    env._env.reset = timed(totals, "reset", env._env.reset)  # the model's reset (a reload where the code reloads)
    env._env.step = timed(totals, "physics", env._env.step)  # LIBERO's control step, settle steps included
    env._observe = timed(totals, "observe", env._observe)  # the cameras' renders, and reading the state
    expert.act = timed(totals, "expert", expert.act)
    walls, steps = [], []
    for variation in range(episodes + 1):
        totals.clear()
        began = time.perf_counter()
        episode = expert_episode(env, expert, variation, 0.1, noise_generator(task, variation))
        if variation:  # the first one warms up
            walls.append((time.perf_counter() - began, dict(totals)))
            steps.append(len(episode.actions))
    env.close()
    wall = sum(seconds for seconds, _ in walls) / episodes
    parts = {part: sum(split.get(part, 0.0) for _, split in walls) / episodes for part in PARTS[:-1]}
    parts["other"] = wall - sum(parts.values())
    return {"task": task, "episodes": episodes, "mean_steps": sum(steps) / episodes, "seconds": wall, "parts": parts}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("output", type=Path)
    parser.add_argument("--tasks", default=",".join(TASKS))
    parser.add_argument("--episodes", type=int, default=3)
    parser.add_argument("--image-size", type=int, default=64)
    parser.add_argument("--env", default="libero", help="libero, or libero-lod (simplified visual meshes)")
    args = parser.parse_args()
    os.environ.setdefault("MUJOCO_GL", "egl")
    rows = [measure(task, args.episodes, args.image_size, args.env) for task in args.tasks.split(",")]
    write_json(
        args.output / "collection_cost.json",
        {"rows": rows, "env": args.env, "image_size": args.image_size, "machine": machine(), "versions": versions()},
    )
    table = markdown_table(
        ["task", "steps", "s a demonstration", *(f"{part} s" for part in PARTS)],
        [
            [row["task"], f"{row['mean_steps']:.0f}", f"{row['seconds']:.2f}"]
            + [f"{row['parts'][part]:.2f}" for part in PARTS]
            for row in rows
        ],
    )
    write_text(args.output / "collection_cost.md", f"# A LIBERO demonstration's time, part by part\n\n{table}\n")
    print(table)


if __name__ == "__main__":
    main()
