"""Demonstrations from a benchmark's scripted experts: successful episodes only."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from tqdm.auto import tqdm

from snapflow.data.demonstrations import META_FILE, Demonstrations, Episode
from snapflow.envs.base import Benchmark, Environment, Expert
from snapflow.reporting.locks import hold_run_lock

EPISODES_PER_TASK = 30  # successful expert episodes per task (Meta-World has 50 training variations a task)


def check_collection(benchmark: Benchmark, tasks: list[str], episodes_per_task: int) -> int:
    """Refuse unknown tasks and more episodes than the benchmark has training variations (loading the simulator, so
    a missing one is found here); returns that number of variations."""
    benchmark.check_tasks(tasks)
    available = benchmark.num_variations("train")
    if not 1 <= episodes_per_task <= available:
        raise ValueError(
            f"episodes_per_task must be in [1, {available}] ({benchmark.name}'s training variations), got {episodes_per_task}"
        )
    return available


def expert_episode(
    env: Environment, expert: Expert, variation: int
) -> tuple[list[np.ndarray], list[np.ndarray], list[np.ndarray], bool]:
    """One episode of ``expert`` on ``variation``: the states it saw, its actions, the camera images (when ``env``
    renders) and whether the episode succeeded."""
    observation = env.reset(variation, render=True)
    expert.reset(observation)
    states, actions, images, success, done = [], [], [], False, False
    while not done:
        action = expert.act(observation)
        states.append(observation.state)
        actions.append(action)
        if observation.image is not None:
            images.append(observation.image)
        observation, success, done = env.step(action, render=observation.image is not None)
    return states, actions, images, success


def collect_demonstrations(
    benchmark: Benchmark,
    tasks: list[str],
    episodes_per_task: int,
    image_size: int | None = None,
    progress: bool = True,
) -> Demonstrations:
    """Run each task's expert on successive training variations until ``episodes_per_task`` succeed."""
    available = check_collection(benchmark, tasks, episodes_per_task)
    states, actions, images, episodes = [], [], [], []
    bar = tqdm(total=len(tasks) * episodes_per_task, desc="collecting expert demonstrations", disable=not progress)
    for task in tasks:
        env, expert = benchmark.make_env(task, "train", image_size), benchmark.make_expert(task)
        kept = 0
        for variation in range(available):
            if kept == episodes_per_task:
                break
            episode_states, episode_actions, episode_images, success = expert_episode(env, expert, variation)
            if success:
                start = sum(episode.length for episode in episodes)
                episodes.append(Episode(task, variation, start, len(episode_actions)))
                states += episode_states
                actions += episode_actions
                images += episode_images
                kept += 1
                bar.update()
        env.close()
        if kept < episodes_per_task:
            raise RuntimeError(f"the {task} expert succeeded on only {kept} of {available} variations")
    bar.close()
    episode_index = np.concatenate([np.full(e.length, i, dtype=np.int64) for i, e in enumerate(episodes)])
    return Demonstrations(
        np.stack(states),
        np.stack(actions),
        episode_index,
        episodes,
        {task: benchmark.instruction(task) for task in tasks},
        np.stack(images) if images else None,
        benchmark.name,
    )


def collect(
    benchmark: Benchmark,
    tasks: list[str],
    episodes_per_task: int = EPISODES_PER_TASK,
    output: str | Path = "outputs/data",
    image_size: int | None = None,
    progress: bool = True,
) -> Demonstrations:
    """:func:`collect_demonstrations`, saved to ``output`` (never over earlier demonstrations), which is held from the first
    episode to the last file: another process collecting into it is refused with
    :class:`~snapflow.reporting.locks.RunLockedError`."""
    check_collection(benchmark, tasks, episodes_per_task)  # before the output folder is created
    with hold_run_lock(output, "snapflow collect"):
        if (Path(output) / META_FILE).is_file():
            raise FileExistsError(f"{output} already holds demonstrations; choose another --output")
        demonstrations = collect_demonstrations(benchmark, tasks, episodes_per_task, image_size, progress)
        demonstrations.save(output)
    return demonstrations


__all__ = ["EPISODES_PER_TASK", "check_collection", "expert_episode", "collect_demonstrations", "collect"]
