"""Meta-World MT10 as a language-conditioned benchmark, with its own scripted experts for demonstrations.

Observation = Meta-World's 39-d state vector + a natural-language instruction + optionally a camera
image, rendered off-screen on the CPU (``MUJOCO_GL=egl`` by default, ``osmesa`` also works). Success is the
environment's own ``info["success"]``; an episode stops at success or at the benchmark's 500-step limit.
Task variations (object and goal positions) come from Meta-World's own sampler: training demonstrations
use the variations of ``MT10(seed=TRAIN_SEED)``, evaluation those of ``MT10(seed=EVAL_SEED)``, which no
demonstration saw.
"""

from __future__ import annotations

import functools
import os
import warnings
from dataclasses import dataclass
from typing import Any

import numpy as np

from snapflow.envs.via_points import ViaPointTracker

# MuJoCo picks its off-screen GL backend when first imported; EGL (Mesa) renders on a CPU-only machine.
os.environ.setdefault("MUJOCO_GL", "egl")

MT10_INSTRUCTIONS: dict[str, str] = {
    "reach-v3": "reach the goal position with the gripper",
    "push-v3": "push the puck to the goal",
    "pick-place-v3": "pick up the puck and place it at the goal",
    "door-open-v3": "open the door by its handle",
    "drawer-open-v3": "pull the drawer open",
    "drawer-close-v3": "push the drawer closed",
    "button-press-topdown-v3": "press the button from the top",
    "peg-insert-side-v3": "insert the peg into the hole from the side",
    "window-open-v3": "slide the window open",
    "window-close-v3": "slide the window closed",
}
EXPERT_POLICIES: dict[str, str] = {
    "reach-v3": "SawyerReachV3Policy",
    "push-v3": "SawyerPushV3Policy",
    "pick-place-v3": "SawyerPickPlaceV3Policy",
    "door-open-v3": "SawyerDoorOpenV3Policy",
    "drawer-open-v3": "SawyerDrawerOpenV3Policy",
    "drawer-close-v3": "SawyerDrawerCloseV3Policy",
    "button-press-topdown-v3": "SawyerButtonPressTopdownV3Policy",
    "peg-insert-side-v3": "SawyerPegInsertionSideV3Policy",
    "window-open-v3": "SawyerWindowOpenV3Policy",
    "window-close-v3": "SawyerWindowCloseV3Policy",
}
MT10_TASKS: tuple[str, ...] = tuple(MT10_INSTRUCTIONS)
STATE_DIM = 39
ACTION_DIM = 4
MAX_EPISODE_STEPS = 500
TRAIN_SEED = 0
EVAL_SEED = 1
SPLIT_SEEDS = {"train": TRAIN_SEED, "eval": EVAL_SEED}


def check_tasks(tasks: list[str] | tuple[str, ...]) -> list[str]:
    """Return ``tasks`` if all are MT10 task names, else raise a ValueError listing the valid ones."""
    unknown = [task for task in tasks if task not in MT10_INSTRUCTIONS]
    if unknown:
        raise ValueError(f"unknown Meta-World task(s) {unknown}; MT10 has {list(MT10_TASKS)}")
    if not tasks:
        raise ValueError("no task given")
    return list(tasks)


@functools.lru_cache(maxsize=2)
def _benchmark(seed: int) -> Any:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        import metaworld

        return metaworld.MT10(seed=seed)


def num_variations(split: str) -> int:
    """How many variations Meta-World's sampler provides per task in one split (50 in Meta-World 3)."""
    benchmark = _benchmark(SPLIT_SEEDS[split])
    return sum(task.env_name == MT10_TASKS[0] for task in benchmark.train_tasks)


@dataclass(frozen=True)
class Observation:
    state: np.ndarray  # (39,) float32
    instruction: str
    image: np.ndarray | None = None  # (H, W, 3) uint8, only when rendering was asked for


class MetaWorldEnv:
    """One MT10 task; ``reset(variation)`` picks a variation of the split from Meta-World's own sampler.

    ``via_points=True`` is the multimodal variant: an episode still ends at the task's success, but counts
    as a success only if the hand passed a via-point before (see :mod:`snapflow.envs.via_points`).
    """

    def __init__(self, task: str, split: str = "train", image_size: int | None = None, via_points: bool = False) -> None:
        check_tasks([task])
        if split not in SPLIT_SEEDS:
            raise ValueError(f"split must be one of {list(SPLIT_SEEDS)}, got {split!r}")
        self.task = task
        self.split = split
        self.instruction = MT10_INSTRUCTIONS[task]
        self.image_size = image_size
        benchmark = _benchmark(SPLIT_SEEDS[split])
        self._variations = [t for t in benchmark.train_tasks if t.env_name == task]
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            if image_size:
                self._env = benchmark.train_classes[task](
                    render_mode="rgb_array", camera_name="corner", width=image_size, height=image_size
                )
                # Shadows and multisampling cost most of a CPU-rendered frame and add nothing at this size.
                self._env.model.vis.quality.shadowsize = 0
                self._env.model.vis.quality.offsamples = 0
            else:
                self._env = benchmark.train_classes[task]()
        self.steps = 0
        # the multimodal variant (see snapflow.envs.via_points): success also needs a via-point visited first
        self._via_points = ViaPointTracker() if via_points else None

    def _observe(self, state: np.ndarray, render: bool) -> Observation:
        image = None
        if render and self.image_size:
            image = np.ascontiguousarray(self._env.render()[::-1])  # MuJoCo frames come out upside down
        return Observation(state.astype(np.float32), self.instruction, image)

    def reset(self, variation: int, render: bool = True) -> Observation:
        if not 0 <= variation < len(self._variations):
            raise ValueError(f"variation must be in [0, {len(self._variations)}), got {variation}")
        self._env.set_task(self._variations[variation])
        state, _ = self._env.reset()
        self.steps = 0
        if self._via_points is not None:
            self._via_points.reset(state)
        return self._observe(state, render)

    def step(self, action: np.ndarray, render: bool = False) -> tuple[Observation, bool, bool]:
        """Apply one action; returns (observation, success, done). Render only when asked (re-planning steps)."""
        state, _, _, _, info = self._env.step(np.clip(np.asarray(action, dtype=np.float32), -1.0, 1.0))
        self.steps += 1
        task_success = bool(info["success"])
        visited = self._via_points is None or self._via_points.update(state)
        success = task_success and visited
        return self._observe(state, render), success, task_success or self.steps >= MAX_EPISODE_STEPS

    def close(self) -> None:
        self._env.close()


def make_expert(task: str) -> Any:
    """Meta-World's scripted expert policy for ``task`` (``get_action(state) -> action``)."""
    check_tasks([task])
    import metaworld.policies

    return getattr(metaworld.policies, EXPERT_POLICIES[task])()


__all__ = [
    "MT10_TASKS",
    "MT10_INSTRUCTIONS",
    "STATE_DIM",
    "ACTION_DIM",
    "MAX_EPISODE_STEPS",
    "Observation",
    "MetaWorldEnv",
    "make_expert",
    "check_tasks",
    "num_variations",
]
