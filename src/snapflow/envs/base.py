"""The environment interface: a benchmark of language-conditioned tasks, each with variations, a scripted expert,
and episodes that end at success or a step limit.

Collection (:mod:`snapflow.data.collect`) and closed-loop evaluation (:mod:`snapflow.evaluation.closed_loop`) use
nothing else, so a new simulator is one module implementing :class:`Benchmark` and one line in
:mod:`snapflow.envs.factory`.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from snapflow.errors import InvalidInputError

SPLITS = ("train", "eval")


@dataclass(frozen=True)
class Observation:
    state: np.ndarray  # (state_dim,) float32
    instruction: str
    image: np.ndarray | None = None  # (H, W, 3) uint8, only when rendering was asked for
    # the other cameras' frames by name (a benchmark with several cameras; ``image`` is its first camera)
    extra_images: Mapping[str, np.ndarray] = field(default_factory=dict)
    # simulator facts only scripted experts read (object poses): never part of what a policy is shown
    privileged: Mapping[str, np.ndarray] = field(default_factory=dict)


class Environment(ABC):
    """One task of a benchmark; ``reset(variation)`` starts an episode on one of the split's variations."""

    task: str
    instruction: str
    steps: int  # actions taken in the current episode

    @abstractmethod
    def reset(self, variation: int, render: bool = True) -> Observation:
        """Start an episode; ``render`` asks for the camera image (when the environment has a camera)."""

    @abstractmethod
    def step(self, action: np.ndarray, render: bool = False) -> tuple[Observation, bool, bool]:
        """Apply one action; returns (observation, success, done). Render only when asked (re-planning steps)."""

    @abstractmethod
    def close(self) -> None: ...

    def path_mode(self) -> int | None:
        """Which of its benchmark's :attr:`~Benchmark.path_modes` the current episode's path took so far: an index
        into them, -1 for none; ``None`` where the benchmark has no modes."""
        return None


class Expert(Protocol):
    """A scripted demonstrator: ``reset`` at each episode's first observation, then ``act`` at every step."""

    def reset(self, observation: Observation) -> None: ...

    def act(self, observation: Observation) -> np.ndarray: ...


class Benchmark(ABC):
    """A suite of tasks with training and evaluation variations (no evaluation variation is shown in training)."""

    name: str  # its name in the registry (snapflow.envs.factory)
    title: str  # for people: report titles
    state_dim: int
    action_dim: int
    max_episode_steps: int
    fps: int  # control steps per simulated second (a LeRobotDataset records it)
    camera: str  # the camera its images are rendered from
    extra_cameras: tuple[str, ...] = ()  # the other cameras it can render (their frames: Observation.extra_images)
    # environments one evaluation process holds at once, which their memory decides: Meta-World's 200 take ~4 GB
    max_envs: int = 200
    # the distinct ways its experts do every task, where it was built to have several (the via-point variant), and
    # the share of demonstrations that take each: an episode's path is scored against them (mode coverage)
    path_modes: tuple[str, ...] = ()
    path_mode_weights: tuple[float, ...] = ()

    @property
    @abstractmethod
    def tasks(self) -> tuple[str, ...]:
        """Every task of the benchmark, in its canonical order."""

    @property
    def task_sets(self) -> dict[str, tuple[str, ...]]:
        """Named sets of tasks (``--tasks mt10``); the first is the default. Unless a benchmark names its own: one
        set, ``all``."""
        return {"all": self.tasks}

    @property
    def default_tasks(self) -> tuple[str, ...]:
        """The tasks of the first set of :attr:`task_sets`: what ``--tasks`` means when not given."""
        return next(iter(self.task_sets.values()))

    def describe(self, tasks: Sequence[str]) -> str:
        """The benchmark's title for a run on ``tasks``, naming the set they are when they are one (report titles)."""
        named = next((name for name, members in self.task_sets.items() if list(members) == list(tasks)), None)
        return (
            f"{self.title} {named.upper()}" if named else f"{self.title} ({len(tasks)} task{'s' * (len(tasks) != 1)})"
        )

    @abstractmethod
    def instruction(self, task: str) -> str:
        """The natural-language instruction of ``task``."""

    @abstractmethod
    def num_variations(self, split: str) -> int:
        """How many variations each task has in ``split`` (one of :data:`SPLITS`)."""

    @abstractmethod
    def make_env(
        self, task: str, split: str, image_size: int | None = None, extra_cameras: Sequence[str] | None = None
    ) -> Environment:
        """``task`` on ``split``'s variations; ``image_size``: also render a square camera image of that side, from
        :attr:`camera` and the :attr:`extra_cameras` named in ``extra_cameras`` (``None``: all of them; a policy
        that reads fewer is evaluated without paying for the others' frames). Names are checked by
        :meth:`check_cameras`."""

    @abstractmethod
    def make_expert(self, task: str) -> Expert:
        """The scripted expert of ``task``."""

    def check_tasks(self, tasks: Sequence[str]) -> list[str]:
        """``tasks`` if all are tasks of this benchmark, else a ValueError listing the valid ones."""
        unknown = [task for task in tasks if task not in self.tasks]
        if unknown:
            raise InvalidInputError(
                f"unknown {self.name} task(s) {unknown}; give a set ({', '.join(self.task_sets)}) or tasks of "
                f"{list(self.tasks)}"
            )
        if not tasks:
            raise InvalidInputError("no task given")
        return list(tasks)

    def resolve_tasks(self, value: str | Sequence[str]) -> list[str]:
        """The tasks ``value`` names: sets of :attr:`task_sets` and task names, in a list or one string of
        comma-separated names (``libero_spatial,libero_object``), in order without repeats, checked by
        :meth:`check_tasks`."""
        if isinstance(value, str):
            value = [name.strip() for name in value.split(",") if name.strip()]
        tasks = [task for name in value for task in self.task_sets.get(name, (name,))]
        return self.check_tasks(list(dict.fromkeys(tasks)))

    def check_cameras(self, extra_cameras: Sequence[str] | None) -> tuple[str, ...]:
        """The extra cameras ``extra_cameras`` names (``None``: all of :attr:`extra_cameras`), or a ValueError naming
        the ones this benchmark has."""
        if extra_cameras is None:
            return self.extra_cameras
        unknown = [name for name in extra_cameras if name not in self.extra_cameras]
        if unknown:
            raise InvalidInputError(
                f"{self.name} has no camera(s) {unknown}: besides its main camera {self.camera!r} it renders "
                f"{list(self.extra_cameras) or 'none'}"
            )
        return tuple(dict.fromkeys(extra_cameras))

    def check_episodes(self, split: str, episodes_per_task: int, first_variation: int = 0) -> int:
        """Refuse more episodes a task than ``split`` has variations from ``first_variation`` on (each episode starts
        on its own); returns the number of variations of the split."""
        available = self.num_variations(split)  # checks the split too
        if first_variation < 0 or not 1 <= episodes_per_task <= available - first_variation:
            start = f" from variation {first_variation}" if first_variation else ""
            raise InvalidInputError(
                f"episodes per task must be in [1, {available - first_variation}] ({self.name}'s {available} "
                f"{'training' if split == 'train' else 'evaluation'} variations{start}), got {episodes_per_task}"
            )
        return available

    def check_split(self, split: str) -> None:
        if split not in SPLITS:
            raise InvalidInputError(f"split must be one of {list(SPLITS)}, got {split!r}")


__all__ = ["SPLITS", "Observation", "Environment", "Expert", "Benchmark"]
