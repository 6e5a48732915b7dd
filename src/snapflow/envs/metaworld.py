"""Meta-World 3 (MT10 and MT50) as a language-conditioned benchmark, with its own scripted experts for demonstrations.

Observation = Meta-World's 39-d state vector + a natural-language instruction + optionally a camera
image, rendered off-screen on the CPU (``MUJOCO_GL=egl`` unless set, ``osmesa`` also works). Success is the
environment's own ``info["success"]``; an episode stops at success or at the benchmark's 500-step limit.
Task variations (object and goal positions) come from Meta-World's own sampler: training demonstrations
use the variations of seed ``SPLIT_SEEDS["train"]``, evaluation those of ``SPLIT_SEEDS["eval"]``, which no
demonstration saw. An MT10 task draws them from ``MT10(seed)``, as every MT10 result here was measured; any other
task from ``MT1(task, seed)`` (building all of ``MT50`` takes ~45 s a process, one ``MT1`` ~1 s).

``MetaWorld(via_points=True)`` is the multimodal variant (:mod:`snapflow.envs.via_points`): its experts detour by
a via-point and its episodes succeed only through one.
"""

from __future__ import annotations

import functools
import os
import warnings
import zlib
from collections.abc import Sequence
from typing import Any

import numpy as np

from snapflow.envs.base import Benchmark, Environment, Observation
from snapflow.envs.via_points import VIA_POINT_MODE_WEIGHTS, VIA_POINT_MODES, ViaPointExpert, ViaPointTracker
from snapflow.errors import InvalidInputError

INSTRUCTIONS: dict[str, str] = {  # every Meta-World 3 task, in MT50's order
    "assembly-v3": "pick up the nut and place it onto the peg",
    "basketball-v3": "dunk the basketball into the basket",
    "bin-picking-v3": "move the puck from one bin into the other",
    "box-close-v3": "grasp the lid and close the box with it",
    "button-press-topdown-v3": "press the button from the top",
    "button-press-topdown-wall-v3": "press the button from the top behind a short wall",
    "button-press-v3": "press the button from the front",
    "button-press-wall-v3": "press the button from the front behind a short wall",
    "coffee-button-v3": "push the button on the coffee machine",
    "coffee-pull-v3": "pull the mug away from the coffee machine",
    "coffee-push-v3": "push the mug under the coffee machine",
    "dial-turn-v3": "rotate the dial half a turn",
    "disassemble-v3": "pick the nut up off the peg",
    "door-close-v3": "push the door closed",
    "door-lock-v3": "lock the door by turning the lock down",
    "door-open-v3": "open the door by its handle",
    "door-unlock-v3": "unlock the door by turning the lock up",
    "hand-insert-v3": "insert the gripper into the hole",
    "drawer-close-v3": "push the drawer closed",
    "drawer-open-v3": "pull the drawer open",
    "faucet-open-v3": "turn the faucet handle to open it",
    "faucet-close-v3": "turn the faucet handle to close it",
    "hammer-v3": "hammer the nail into the wall",
    "handle-press-side-v3": "press the handle down from the side",
    "handle-press-v3": "press the handle down",
    "handle-pull-side-v3": "pull the handle up from the side",
    "handle-pull-v3": "pull the handle up",
    "lever-pull-v3": "pull the lever up",
    "pick-place-wall-v3": "pick up the puck and place it at the goal over a wall",
    "pick-out-of-hole-v3": "pick the peg out of the hole",
    "pick-place-v3": "pick up the puck and place it at the goal",
    "plate-slide-v3": "slide the plate into the cabinet",
    "plate-slide-side-v3": "slide the plate into the cabinet sideways",
    "plate-slide-back-v3": "slide the plate back out of the cabinet",
    "plate-slide-back-side-v3": "slide the plate back out of the cabinet sideways",
    "peg-insert-side-v3": "insert the peg into the hole from the side",
    "peg-unplug-side-v3": "unplug the peg from the side",
    "soccer-v3": "kick the soccer ball into the goal",
    "stick-push-v3": "grasp the stick and push the box with it",
    "stick-pull-v3": "grasp the stick and pull the box with it",
    "push-v3": "push the puck to the goal",
    "push-wall-v3": "push the puck to the goal around a wall",
    "push-back-v3": "pull the puck back to the goal",
    "reach-v3": "reach the goal position with the gripper",
    "reach-wall-v3": "reach the goal position with the gripper over a wall",
    "shelf-place-v3": "pick up the puck and place it on the shelf",
    "sweep-into-v3": "sweep the puck into the hole",
    "sweep-v3": "sweep the puck off the table",
    "window-open-v3": "slide the window open",
    "window-close-v3": "slide the window closed",
}
MT50_TASKS: tuple[str, ...] = tuple(INSTRUCTIONS)
MT10_TASKS: tuple[str, ...] = (
    "reach-v3",
    "push-v3",
    "pick-place-v3",
    "door-open-v3",
    "drawer-open-v3",
    "drawer-close-v3",
    "button-press-topdown-v3",
    "peg-insert-side-v3",
    "window-open-v3",
    "window-close-v3",
)
MT10_INSTRUCTIONS: dict[str, str] = {task: INSTRUCTIONS[task] for task in MT10_TASKS}
TASK_SETS: dict[str, tuple[str, ...]] = {"mt10": MT10_TASKS, "mt50": MT50_TASKS}
STATE_DIM = 39
ACTION_DIM = 4
MAX_EPISODE_STEPS = 500
FPS = 80  # 5 MuJoCo steps of 2.5 ms per action, as LeRobot's Meta-World environment records it
CAMERA = "corner"
SPLIT_SEEDS = {"train": 0, "eval": 1}


def _suite(task: str, seed: int) -> Any:
    """The Meta-World benchmark object that samples ``task``'s variations: MT10 for an MT10 task, else MT1."""
    return _benchmark("MT10" if task in MT10_TASKS else task, seed)


@functools.cache
def _benchmark(name: str, seed: int) -> Any:
    """Meta-World's MT10 (``name`` "MT10") or the MT1 of the task ``name``, built once a process: MT10 resets each
    of its environments 50 times as it samples their variations (~8 s on one core), and every MT10 task reads the
    same object (its tasks and classes, never changed)."""
    # MuJoCo picks its off-screen GL backend when first imported; EGL (Mesa) renders on a CPU-only machine
    os.environ.setdefault("MUJOCO_GL", "egl")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        import metaworld

        return metaworld.MT10(seed=seed) if name == "MT10" else metaworld.MT1(name, seed=seed)


class MetaWorldEnv(Environment):
    """One Meta-World task; ``reset(variation)`` picks a variation of the split from Meta-World's own sampler.

    ``via_points=True``: an episode still ends at the task's success, but counts as a success only if the hand
    passed a via-point before (see :mod:`snapflow.envs.via_points`).
    """

    def __init__(
        self, task: str, split: str = "train", image_size: int | None = None, via_points: bool = False
    ) -> None:
        benchmark = MetaWorld(via_points)
        benchmark.check_tasks([task])
        benchmark.check_split(split)
        self.task = task
        self.split = split
        self.instruction = INSTRUCTIONS[task]
        self.image_size = image_size
        suite = _suite(task, SPLIT_SEEDS[split])
        self._variations = [t for t in suite.train_tasks if t.env_name == task]
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            if image_size:
                self._env = suite.train_classes[task](
                    render_mode="rgb_array", camera_name=CAMERA, width=image_size, height=image_size
                )
                # Shadows and multisampling cost most of a CPU-rendered frame and add nothing at this size.
                self._env.model.vis.quality.shadowsize = 0
                self._env.model.vis.quality.offsamples = 0
            else:
                self._env = suite.train_classes[task]()
        self.steps = 0
        self._via_points = ViaPointTracker() if via_points else None

    def _observe(self, state: np.ndarray, render: bool) -> Observation:
        image = None
        if render and self.image_size:
            image = np.ascontiguousarray(self._env.render()[::-1])  # MuJoCo frames come out upside down
        return Observation(state.astype(np.float32), self.instruction, image)

    def reset(self, variation: int, render: bool = True) -> Observation:
        if not 0 <= variation < len(self._variations):
            raise InvalidInputError(f"variation must be in [0, {len(self._variations)}), got {variation}")
        self._env.set_task(self._variations[variation])
        state, _ = self._env.reset()
        self.steps = 0
        if self._via_points is not None:
            self._via_points.reset(state)
        return self._observe(state, render)

    def step(self, action: np.ndarray, render: bool = False) -> tuple[Observation, bool, bool]:
        state, _, _, _, info = self._env.step(np.clip(np.asarray(action, dtype=np.float32), -1.0, 1.0))
        self.steps += 1
        task_success = bool(info["success"])
        visited = self._via_points is None or self._via_points.update(state)
        success = task_success and visited
        return self._observe(state, render), success, task_success or self.steps >= MAX_EPISODE_STEPS

    def path_mode(self) -> int | None:
        """In the via-point variant, the via-point the hand passed first (0 left, 1 right, -1 neither yet)."""
        return None if self._via_points is None else self._via_points.first

    def close(self) -> None:
        self._env.close()


class ScriptedExpert:
    """Meta-World's scripted policy of a task, behind the :class:`snapflow.envs.base.Expert` interface."""

    def __init__(self, policy: Any) -> None:
        self.policy = policy

    def reset(self, observation: Observation) -> None:
        """Meta-World's experts are memoryless."""

    def act(self, observation: Observation) -> np.ndarray:
        """The action the environment applies: the expert's, clipped to Meta-World's [-1, 1] (the experts warn that
        their gains exceed it; that notice is silenced)."""
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", message="Constant.*may be too high")
            action = self.policy.get_action(observation.state)
        return np.clip(np.asarray(action, dtype=np.float32), -1.0, 1.0)


class MetaWorld(Benchmark):
    """Meta-World 3's 50 tasks (sets ``mt10``, the default, and ``mt50``) or its multimodal via-point variant."""

    state_dim = STATE_DIM
    action_dim = ACTION_DIM
    max_episode_steps = MAX_EPISODE_STEPS
    fps = FPS
    camera = CAMERA

    def __init__(self, via_points: bool = False) -> None:
        self.via_points = via_points
        self.name = "metaworld-via-points" if via_points else "metaworld"
        self.title = "Meta-World"
        if via_points:
            self.path_modes, self.path_mode_weights = VIA_POINT_MODES, VIA_POINT_MODE_WEIGHTS

    @property
    def tasks(self) -> tuple[str, ...]:
        return MT50_TASKS

    @property
    def task_sets(self) -> dict[str, tuple[str, ...]]:
        return TASK_SETS

    def describe(self, tasks: Sequence[str]) -> str:
        """``Meta-World MT10`` (or MT50, or N tasks), ``, via-point variant`` after it for that variant."""
        described = super().describe(tasks)
        return f"{described}, via-point variant" if self.via_points else described

    def instruction(self, task: str) -> str:
        self.check_tasks([task])
        return INSTRUCTIONS[task]

    def num_variations(self, split: str) -> int:
        """How many variations Meta-World's sampler provides per task in one split (50 in Meta-World 3)."""
        self.check_split(split)
        return sum(task.env_name == MT10_TASKS[0] for task in _suite(MT10_TASKS[0], SPLIT_SEEDS[split]).train_tasks)

    def make_env(
        self, task: str, split: str, image_size: int | None = None, extra_cameras: Sequence[str] | None = None
    ) -> MetaWorldEnv:
        self.check_cameras(extra_cameras)  # one camera: none to add
        return MetaWorldEnv(task, split, image_size, self.via_points)

    def make_expert(self, task: str) -> ScriptedExpert | ViaPointExpert:
        """Meta-World's scripted expert of ``task``; in the via-point variant routed through a via-point drawn per
        episode (left or right) from a generator seeded by the task's name."""
        self.check_tasks([task])
        import metaworld.policies

        expert = ScriptedExpert(metaworld.policies.ENV_POLICY_MAP[task]())
        if self.via_points:
            return ViaPointExpert(expert, np.random.default_rng(zlib.crc32(task.encode())))
        return expert


__all__ = [
    "INSTRUCTIONS",
    "MT10_TASKS",
    "MT10_INSTRUCTIONS",
    "MT50_TASKS",
    "TASK_SETS",
    "STATE_DIM",
    "ACTION_DIM",
    "MAX_EPISODE_STEPS",
    "MetaWorld",
    "MetaWorldEnv",
    "ScriptedExpert",
]
