"""A training reset of LIBERO keeps the model (``LiberoEnv._reset_as_reloaded``) and must leave the scene that LIBERO's
hard reset (the model rebuilt from its MJCF, recompiled, a new render context) leaves, bit for bit: the same draws
from NumPy's generator, model, simulator state and both cameras' frames, right after the reset and its settle steps
and after an episode from there.

One environment makes both resets of a variation in turn, the kept-model one first, so that each but the first follows
an episode (the last fixture poses, a lit burner's colour, the gripper's command left behind), as a collection's resets
do. The tasks: bowls in and on a fixture (the cabinet's open drawer, its top: the placements a plain soft reset got
wrong), a LIBERO-10 task whose stove starts lit (the burner's colour), and a floor scene whose settled state shows
how many times the data was forwarded before the reset's draws (the solver's warm start).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from snapflow.envs.base import Observation
from snapflow.envs.libero import SETTLE_ACTION, SETTLE_STEPS, LiberoEnv

SIZE = 64
EPISODE = 30  # random steps after each reset


def hard_reset(env: LiberoEnv, variation: int) -> Observation:
    """The training reset LiberoEnv made before, the reference: LIBERO's hard reset, then the render settings made
    cheap on the new context and the settle steps. LIBERO appends each load's drawer and knob samplers to those of the
    loads before, so that a hard reset draws such a joint once per load so far; the kept model draws it once, as one
    load's samplers do, and the reference keeps the new load's alone."""
    inner = env._env.env
    samplers = len(inner.object_property_initializers)
    load = inner._load_model

    def load_alone() -> None:
        load()
        del inner.object_property_initializers[: len(inner.object_property_initializers) - samplers]

    inner._load_model, inner.hard_reset = load_alone, True
    env._env.seed(variation)
    try:
        env._env.reset()
    finally:
        del inner._load_model
        inner.hard_reset = False
    env._cheap_rendering(SIZE)
    for _ in range(SETTLE_STEPS):
        raw, _, _, _ = env._env.step(SETTLE_ACTION)
    env.steps = 0
    return env._observe(raw, render=True)


def scene(env: LiberoEnv, observation: Observation) -> dict[str, Any]:
    """What must match: the state, the model's body poses and site colours (the fixtures' drawn poses are written into
    ``body_pos``/``body_quat``), both frames and the generator's position."""
    sim = env._env.env.sim
    generator = np.random.get_state()
    return {
        "state": sim.get_state().flatten(),
        "body_pos": sim.model.body_pos.copy(),
        "body_quat": sim.model.body_quat.copy(),
        "site_rgba": sim.model.site_rgba.copy(),
        "image": observation.image,
        "image2": observation.extra_images["image2"],
        "generator": np.append(generator[1], generator[2]),
    }


def episode(env: LiberoEnv, actions: np.ndarray) -> Observation:
    for action in actions[:-1]:
        env.step(action)
    return env.step(actions[-1], render=True)[0]


def assert_same(kept: dict[str, Any], reloaded: dict[str, Any], when: str) -> None:
    for name in kept:
        np.testing.assert_array_equal(kept[name], reloaded[name], err_msg=f"{name} {when}")


@pytest.mark.slow
@pytest.mark.parametrize("task", ["libero_spatial_4", "libero_10_8", "libero_object_0"])
def test_a_training_reset_leaves_the_scene_a_reloaded_model_leaves(task):
    env = LiberoEnv(task, "train", image_size=SIZE)
    actions = np.random.default_rng(0).uniform(-1.0, 1.0, size=(2, EPISODE, 7))
    try:
        for variation, moves in zip((0, 7), actions, strict=True):
            kept = scene(env, env.reset(variation))
            kept_after = scene(env, episode(env, moves))
            reloaded = scene(env, hard_reset(env, variation))
            reloaded_after = scene(env, episode(env, moves))
            assert_same(kept, reloaded, f"after variation {variation}'s reset")
            assert_same(kept_after, reloaded_after, f"after an episode from variation {variation}")
    finally:
        env.close()
    assert kept["state"][1:].any() and kept["image"].std() > 10  # a scene was compared, not two empty ones
