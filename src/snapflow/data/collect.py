"""Demonstrations from Meta-World's scripted experts: successful episodes only."""

from __future__ import annotations

import warnings
import zlib

import numpy as np
from tqdm.auto import tqdm

from snapflow.data.demonstrations import Demonstrations, Episode
from snapflow.envs.metaworld import MT10_INSTRUCTIONS, MetaWorldEnv, check_tasks, make_expert, num_variations
from snapflow.envs.via_points import ViaPointExpert


def collect_demonstrations(
    tasks: list[str], episodes_per_task: int, image_size: int | None = None, progress: bool = True, via_points: bool = False,
) -> Demonstrations:
    """Run each task's expert on successive training variations until ``episodes_per_task`` succeed.

    ``via_points=True``: the multimodal variant, each episode routed through a via-point drawn at random
    (left or right, from a generator seeded per task) before the expert takes over.
    """
    check_tasks(tasks)
    warnings.filterwarnings("ignore", message="Constant.*may be too high")  # the experts' own clipping notice
    available = num_variations("train")
    if not 1 <= episodes_per_task <= available:
        raise ValueError(f"episodes_per_task must be in [1, {available}] (Meta-World's training variations), got {episodes_per_task}")
    states, actions, images, episodes = [], [], [], []
    bar = tqdm(total=len(tasks) * episodes_per_task, desc="collecting expert demonstrations", disable=not progress)
    for task in tasks:
        env, expert = MetaWorldEnv(task, "train", image_size, via_points), make_expert(task)
        if via_points:
            expert, sides = ViaPointExpert(expert), np.random.default_rng(zlib.crc32(task.encode()))
        kept = 0
        for variation in range(available):
            if kept == episodes_per_task:
                break
            observation = env.reset(variation, render=True)
            if via_points:
                expert.reset(observation.state, int(sides.integers(2)))
            episode_states, episode_actions, episode_images, success, done = [], [], [], False, False
            while not done:
                action = np.clip(expert.get_action(observation.state), -1.0, 1.0).astype(np.float32)
                episode_states.append(observation.state)
                episode_actions.append(action)
                if observation.image is not None:
                    episode_images.append(observation.image)
                observation, success, done = env.step(action, render=image_size is not None)
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
        np.stack(states), np.stack(actions), episode_index, episodes,
        {task: MT10_INSTRUCTIONS[task] for task in tasks}, np.stack(images) if images else None,
    )


__all__ = ["collect_demonstrations"]
