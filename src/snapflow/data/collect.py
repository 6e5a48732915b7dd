"""Demonstrations from a benchmark's scripted experts: successful episodes only.

With ``action_noise`` the environment executes the expert's action plus Gaussian noise while the demonstration keeps
the expert's own action: DART (Laskey et al., 2017). A policy trained on noise-free demonstrations meets, in closed
loop, states a little off the experts' paths that no demonstration shows, and its errors compound there; noise at
collection puts such states in the data, each labelled with how the expert steers back from it.
"""

from __future__ import annotations

import shutil
import zlib
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from tqdm.auto import tqdm

from snapflow.data.demonstrations import META_FILE, Demonstrations, Episode, check_action_noise
from snapflow.envs.base import Benchmark, Environment, Expert
from snapflow.errors import InvalidInputError
from snapflow.reporting.locks import hold_run_lock

EPISODES_PER_TASK = 30  # successful expert episodes per task (Meta-World has 50 training variations a task)


def check_collection(
    benchmark: Benchmark, tasks: list[str], episodes_per_task: int, action_noise: float = 0.0, first_variation: int = 0
) -> int:
    """Refuse unknown tasks, more episodes than the benchmark has training variations from ``first_variation`` on
    (loading the simulator, so a missing one is found here) and negative noise; returns that number of variations."""
    check_action_noise(action_noise)
    benchmark.check_tasks(tasks)
    return benchmark.check_episodes("train", episodes_per_task, first_variation)


@dataclass
class ExpertEpisode:
    """One episode of a scripted expert: the states it saw, its actions, the camera frames (when the environment
    renders: the main camera's, and the other cameras' by name) and whether it succeeded."""

    states: list[np.ndarray] = field(default_factory=list)
    actions: list[np.ndarray] = field(default_factory=list)
    images: list[np.ndarray] = field(default_factory=list)
    extra_images: dict[str, list[np.ndarray]] = field(default_factory=dict)
    success: bool = False


def expert_episode(
    env: Environment, expert: Expert, variation: int, action_noise: float = 0.0, rng: np.random.Generator | None = None
) -> ExpertEpisode:
    """One episode of ``expert`` on ``variation``, to its end; with ``action_noise``, each executed action is the
    expert's plus Gaussian noise of that standard deviation (drawn from ``rng``), and the recorded one the expert's."""
    if action_noise and rng is None:
        raise ValueError("action_noise needs an rng to draw the noise from")
    observation = env.reset(variation, render=True)
    expert.reset(observation)
    episode, done = ExpertEpisode(), False
    while not done:
        action = expert.act(observation)
        episode.states.append(observation.state)
        episode.actions.append(action)
        if observation.image is not None:
            episode.images.append(observation.image)
        for name, image in observation.extra_images.items():
            episode.extra_images.setdefault(name, []).append(image)
        executed = action + rng.normal(0.0, action_noise, np.shape(action)) if action_noise else action
        observation, episode.success, done = env.step(executed, render=observation.image is not None)
    return episode


def noise_generator(task: str, variation: int, seed: int = 0) -> np.random.Generator:
    """The collection noise of one (task, variation): the same in any collection of that task with the same ``seed``,
    whichever tasks are collected beside it and in whichever order; another seed, other noise."""
    # seed 0: the noise of every collection made before a seed could be chosen
    return np.random.default_rng([zlib.crc32(task.encode()), variation, *([seed] if seed else [])])


def collect_demonstrations(
    benchmark: Benchmark,
    tasks: list[str],
    episodes_per_task: int,
    image_size: int | None = None,
    progress: bool = True,
    extra_cameras: Sequence[str] | None = None,
    action_noise: float = 0.0,
    first_variation: int = 0,
    noise_seed: int = 0,
) -> Demonstrations:
    """Run each task's expert on successive training variations from ``first_variation`` on until
    ``episodes_per_task`` succeed; with ``image_size``, the frames of the main camera and of the benchmark's
    ``extra_cameras`` (None: all of them) too; with ``action_noise``, the executed actions perturbed (see the module's
    docstring) by noise drawn with ``noise_seed``. A second set of demonstrations beside a first is another
    ``first_variation`` (other resets) or another ``noise_seed`` (other noise on the same resets)."""
    available = check_collection(benchmark, tasks, episodes_per_task, action_noise, first_variation)
    states, actions, images, extra_images, episodes = [], [], [], {}, []
    bar = tqdm(total=len(tasks) * episodes_per_task, desc="collecting expert demonstrations", disable=not progress)
    for task in tasks:
        env, expert = benchmark.make_env(task, "train", image_size, extra_cameras), benchmark.make_expert(task)
        kept = 0
        for variation in range(first_variation, available):
            if kept == episodes_per_task:
                break
            noise = noise_generator(task, variation, noise_seed)
            episode = expert_episode(env, expert, variation, action_noise, noise)
            if episode.success:
                start = sum(kept_episode.length for kept_episode in episodes)
                episodes.append(Episode(task, variation, start, len(episode.actions)))
                states += episode.states
                actions += episode.actions
                images += episode.images
                for name, frames in episode.extra_images.items():
                    extra_images.setdefault(name, []).extend(frames)
                kept += 1
                bar.update()
        env.close()
        if kept < episodes_per_task:
            raise RuntimeError(
                f"the {task} expert succeeded on only {kept} of {available - first_variation} variations"
            )
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
        {name: np.stack(frames) for name, frames in extra_images.items()},
        action_noise,
        noise_seed,
        first_variation,
    )


#: where :func:`collect` keeps each finished task's demonstrations until all are put together
PARTS = ".parts"


def collect(
    benchmark: Benchmark,
    tasks: list[str],
    episodes_per_task: int = EPISODES_PER_TASK,
    output: str | Path = "outputs/data",
    image_size: int | None = None,
    progress: bool = True,
    extra_cameras: Sequence[str] | None = None,
    action_noise: float = 0.0,
    first_variation: int = 0,
    noise_seed: int = 0,
) -> Demonstrations:
    """:func:`collect_demonstrations`, saved to ``output`` (never over earlier demonstrations), which is held from the
    first episode to the last file: another process collecting into it is refused with
    :class:`~snapflow.reporting.locks.RunLockedError`.

    Task by task: each finished task's demonstrations are saved in ``output/.parts/<task>`` as it ends, and the same
    call after an interruption collects only the tasks not saved there (every reset and its noise are seeded, so the
    result equals an uninterrupted run's); the parts are put together in ``output`` once all are there."""
    # before the output folder is created
    check_collection(benchmark, tasks, episodes_per_task, action_noise, first_variation)
    benchmark.check_cameras(extra_cameras)
    settings = (episodes_per_task, image_size, action_noise, first_variation, noise_seed)
    with hold_run_lock(output, "snapflow collect"):
        if (Path(output) / META_FILE).is_file():
            raise FileExistsError(f"{output} already holds demonstrations; choose another --output")
        parts = []
        for task in tasks:
            folder = Path(output) / PARTS / task
            if (folder / META_FILE).is_file():  # written last: the part is whole
                part = Demonstrations.load(folder)
                _check_part(part, folder, benchmark.name, settings, extra_cameras)
            else:
                part = collect_demonstrations(
                    benchmark,
                    [task],
                    episodes_per_task,
                    image_size,
                    progress,
                    extra_cameras,
                    action_noise,
                    first_variation,
                    noise_seed,
                )
                part.save(folder)
            parts.append(part)
        demonstrations = Demonstrations.concatenate(parts)
        demonstrations.save(output)
        shutil.rmtree(Path(output) / PARTS)
    return demonstrations


def _check_part(
    part: Demonstrations,
    folder: Path,
    env: str,
    settings: tuple[int, int | None, float, int, int],
    extra_cameras: Sequence[str] | None,
) -> None:
    """Refuse a task's saved part that another collection made: going on from it would mix two collections."""
    size = part.images.shape[1] if part.images is not None else None
    found = (len(part.episodes), size, part.action_noise, part.first_variation, part.noise_seed)
    cameras = list(part.extra_images)
    if part.env != env or found != settings or (extra_cameras is not None and cameras != list(extra_cameras)):
        raise InvalidInputError(
            f"{folder} holds a task of another collection ({part.env}; episodes, image size, action noise, first "
            f"variation, noise seed: {found}; cameras {cameras}): remove it, or choose another --output"
        )


__all__ = [
    "EPISODES_PER_TASK",
    "PARTS",
    "ExpertEpisode",
    "check_collection",
    "expert_episode",
    "noise_generator",
    "collect_demonstrations",
    "collect",
]
