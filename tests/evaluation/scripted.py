"""A scripted benchmark registered for the evaluation tests: no simulator, every action recorded."""

from collections.abc import Sequence

import numpy as np

from snapflow.envs.base import Benchmark, Environment, Observation
from tests.training.fixtures import ACTION_DIM, STATE_DIM, SYNTHETIC_TASKS

EPISODE_STEPS = 6


class ScriptedEnv(Environment):
    """A fixed state per variation; every action is recorded; an episode lasts ``EPISODE_STEPS`` steps and succeeds
    when the first action dimension summed over it is positive."""

    def __init__(self, task: str) -> None:
        self.task, self.instruction, self.steps, self.closed = task, SYNTHETIC_TASKS[task], 0, False
        self.actions: list[np.ndarray] = []
        self.state = np.zeros(STATE_DIM, np.float32)

    def reset(self, variation: int, render: bool = True) -> Observation:
        self.state = np.random.default_rng([variation, len(self.task)]).standard_normal(STATE_DIM).astype(np.float32)
        self.steps, self.actions = 0, []
        return Observation(self.state, self.instruction)

    def step(self, action: np.ndarray, render: bool = False) -> tuple[Observation, bool, bool]:
        self.steps += 1
        self.actions.append(np.asarray(action))
        done = self.steps == EPISODE_STEPS
        return Observation(self.state, self.instruction), done and float(np.sum([a[0] for a in self.actions])) > 0, done

    def close(self) -> None:
        self.closed = True


class ScriptedBenchmark(Benchmark):
    name, title = "scripted", "Scripted test benchmark"
    state_dim, action_dim, max_episode_steps = STATE_DIM, ACTION_DIM, EPISODE_STEPS
    camera, extra_cameras = "image", ("wrist",)

    def __init__(self) -> None:
        self.envs: list[ScriptedEnv] = []
        self.rendered_cameras: list[tuple[str, ...] | None] = []  # each environment's extra cameras, as asked for

    @property
    def tasks(self) -> tuple[str, ...]:
        return tuple(SYNTHETIC_TASKS)

    def instruction(self, task: str) -> str:
        return SYNTHETIC_TASKS[task]

    def num_variations(self, split: str) -> int:
        return 3

    def make_env(
        self, task: str, split: str, image_size: int | None = None, extra_cameras: Sequence[str] | None = None
    ) -> ScriptedEnv:
        self.rendered_cameras.append(None if extra_cameras is None else tuple(extra_cameras))
        self.envs.append(ScriptedEnv(task))
        return self.envs[-1]

    def make_expert(self, task: str):
        raise NotImplementedError


class ModalScriptedEnv(ScriptedEnv):
    """A scripted environment whose path has a mode: the sign of its first action's first entry, 0 above 0.1, 1 below
    -0.1, -1 (neither) between or before any action."""

    def path_mode(self) -> int | None:
        if not self.actions or abs(self.actions[0][0]) <= 0.1:
            return -1
        return 0 if self.actions[0][0] > 0 else 1


class ModalScriptedBenchmark(ScriptedBenchmark):
    name, title = "scripted-modal", "Scripted test benchmark with two path modes"
    path_modes, path_mode_weights = ("up", "down"), (0.5, 0.5)

    def make_env(
        self, task: str, split: str, image_size: int | None = None, extra_cameras: Sequence[str] | None = None
    ) -> ModalScriptedEnv:
        self.envs.append(ModalScriptedEnv(task))
        return self.envs[-1]
