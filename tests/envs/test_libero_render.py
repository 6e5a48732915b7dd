"""Frustum-culled rendering of LIBERO's cameras (``snapflow.envs.libero_render``) against robosuite's ``sim.render``:
the same frames, bit for bit, over a moving arm, with meshes actually culled; culling off where it would not be exact.

Making a LIBERO environment takes 5-10 s, so the test that steps one is marked slow, as in ``test_libero.py``.
"""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from snapflow.envs import libero_render
from snapflow.envs.libero import CAMERAS, LiberoEnv
from snapflow.envs.libero_render import cullable, outside_frustum, render

SIZE = 64  # the collections' image size


def test_the_modules_mujoco_constants_are_mujocos():
    assert libero_render.MESH == mujoco.mjtGeom.mjGEOM_MESH and libero_render.NGROUP == mujoco.mjNGROUP
    assert libero_render.REFLECTION == mujoco.mjtRndFlag.mjRND_REFLECTION
    assert libero_render.SHADOW == mujoco.mjtRndFlag.mjRND_SHADOW


@pytest.mark.slow
def test_culled_frames_are_sim_renders_bit_for_bit_over_a_moving_arm():
    """40 steps of an arm sweeping and turning its wrist: both cameras' frames equal ``sim.render``'s, meshes are
    culled (most in the wrist's view), the geom groups are restored, and the premise holds: each mesh's vertices,
    as its display list draws them, lie in its ``geom_aabb``. With reflections on nothing is culled."""
    env = LiberoEnv("libero_spatial_0", "eval", image_size=SIZE)
    try:
        env.reset(0, render=False)
        sim = env._env.env.sim
        model, data = sim.model._model, sim.data._data
        for geom in np.flatnonzero(model.geom_type == mujoco.mjtGeom.mjGEOM_MESH):
            mesh = model.geom_dataid[geom]
            vertices = model.mesh_vert[model.mesh_vertadr[mesh] : model.mesh_vertadr[mesh] + model.mesh_vertnum[mesh]]
            center, half = model.geom_aabb[geom, :3], model.geom_aabb[geom, 3:]
            assert np.all(np.abs(vertices - center) <= half + 1e-6), sim.model.geom_id2name(geom)
        groups = model.geom_group.copy()
        sim._render_context_offscreen.gl_ctx.make_current()
        culled = dict.fromkeys(CAMERAS.values(), 0)
        for step in range(40):
            phase = step / 40 * 2 * np.pi
            env.step(np.array([0.6 * np.sin(phase), 0.6 * np.cos(phase), 0.3 * np.sin(2 * phase), 0, 0.3, 0.6, -1]))
            for camera in CAMERAS.values():
                expected = sim.render(camera_name=camera, width=SIZE, height=SIZE)
                frame = render(sim, camera, SIZE, SIZE)
                assert frame.shape == (SIZE, SIZE, 3) and frame.dtype == np.uint8 and frame.std() > 10
                np.testing.assert_array_equal(frame, expected, err_msg=f"{camera} at step {step}")
                hidden = outside_frustum(model, data, sim.model.camera_name2id(camera), SIZE, SIZE, cullable(sim))
                culled[camera] += len(hidden)
        np.testing.assert_array_equal(model.geom_group, groups)
        assert culled["robot0_eye_in_hand"] > culled["agentview"] > 0
        scene = sim._render_context_offscreen.scn
        scene.flags[mujoco.mjtRndFlag.mjRND_REFLECTION] = 1  # a geom out of view may be seen in a mirror
        try:
            assert len(cullable(sim)) == 0
        finally:
            scene.flags[mujoco.mjtRndFlag.mjRND_REFLECTION] = 0
    finally:
        env.close()
