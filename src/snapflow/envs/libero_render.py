"""A camera of a robosuite simulation rendered exactly as ``sim.render`` renders it, bit for bit, for less: the mesh
geoms that lie wholly outside the camera's view frustum are left out of the scene.

Why: under software OpenGL (Mesa's llvmpipe, as LIBERO is rendered here) a 64-pixel frame costs the vertex processing
of every mesh triangle MuJoCo submits (~293k a LIBERO frame: a bowl 42k, the robot's pedestal 33k, a Panda link
12-15k), whether or not it lands in the image: MuJoCo culls nothing itself. The wrist camera sees a small part of the
scene (half its triangles or more lie outside its frustum: a frame in ~18 ms instead of ~26), agentview most of it.

Why exact: a geom wholly outside one of the frustum's six planes is clipped whole and produces no fragment, so it
changes no pixel (at a pixel the depth test keeps the last-drawn nearest fragment; a geom without fragments changes
neither which fragment that is nor what is drawn after it). Nothing else in ``mjr_render`` reads it, given that:

- only meshes are culled: never a plane or a box, the geoms ``mjr_render`` may draw as the scene's one reflector (the
  first reflective geom in the scene is drawn apart, and which one is first must not change); the primitives are a
  few hundred triangles and not worth a proof of their drawn extent;
- the remaining geoms keep their order: the scene is built in model order, and the transparent ones are sorted by
  MuJoCo's stable merge sort;
- no reflection and no shadow is drawn (a geom outside the view may be seen in a mirror or cast a shadow into it) and
  the view is mono (a stereo pair is two frusta): :func:`render` culls nothing otherwise. LIBERO renders without
  reflections (``LiberoEnv._cheap_rendering``) and its lights cast no shadow.

The test is conservative: a mesh's box (``geom_aabb``, in the geom's frame, enclosing the vertices its display list
draws as they are) must lie :data:`MARGIN` beyond a plane, against float rounding in GL of ~1e-7 m at these scales.
The frustum is the one ``mjv_updateCamera`` and ``mjr_render`` build for a fixed camera.

How: the culled geoms are moved, for one ``sim.render`` call, into a geom group the render context's ``vopt`` does
not draw, so that ``mjv_updateScene`` leaves them out, then moved back; the rendering itself is robosuite's own path,
untouched. Also measured and not kept: one ``mjv_updateScene`` for both cameras (``mjv_updateCamera`` for the second)
would save ~4 microseconds a frame; testing each mesh's vertices instead of its box would cull ~1% more triangles.
"""

from __future__ import annotations

from typing import Any

import numpy as np

MESH = 7  # mjGEOM_MESH
NGROUP = 6  # mjNGROUP: geom groups beyond it are drawn as the last one
REFLECTION, SHADOW = 2, 0  # mjtRndFlag's mjRND_REFLECTION and mjRND_SHADOW
MARGIN = 1e-3  # metres a mesh's box must lie beyond a frustum plane to be culled


def outside_frustum(
    model: Any, data: Any, camera: int, width: int, height: int, geoms: np.ndarray | None = None
) -> np.ndarray:
    """The mesh geoms among ``geoms`` (default: all of them) whose box lies wholly outside fixed camera ``camera``'s
    view frustum for a ``width`` x ``height`` image. ``model``, ``data``: MuJoCo's ``MjModel`` and ``MjData``, their
    poses those ``mjv_updateScene`` will read. The frustum is ``mjv_updateCamera``'s and ``mjr_render``'s: vertical
    field of view ``cam_fovy``, the viewport's aspect, near and far planes at ``vis.map.znear`` and ``vis.map.zfar``
    times ``stat.extent``. An orthographic camera, or one with intrinsics (a sensor size), culls nothing."""
    if model.cam_orthographic[camera] or model.cam_sensorsize[camera, 1]:
        return np.empty(0, dtype=np.int64)
    geoms = np.arange(model.ngeom) if geoms is None else np.asarray(geoms, dtype=np.int64)
    geoms = geoms[model.geom_type[geoms] == MESH]
    tan_y = np.tan(np.deg2rad(model.cam_fovy[camera]) / 2)
    tan_x = tan_y * width / height  # mjr_render's half-width: the half-height times the viewport's aspect
    znear = model.vis.map.znear * model.stat.extent
    zfar = model.vis.map.zfar * model.stat.extent
    # outward normals of the planes in the camera's frame (x right, y up, looking down -z), and offsets: a point q
    # (relative to the camera) is outside a plane when normal . q + offset > 0
    normals = np.array([[1, 0, tan_x], [-1, 0, tan_x], [0, 1, tan_y], [0, -1, tan_y], [0, 0, 1], [0, 0, -1]])
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    offsets = np.array([0, 0, 0, 0, znear, -zfar])  # nearer than znear: z > -znear; beyond zfar: z < -zfar
    world_normals = normals @ data.cam_xmat[camera].reshape(3, 3).T  # cam_xmat's columns: the camera's axes
    rotations = data.geom_xmat[geoms].reshape(-1, 3, 3)  # geom frame -> world
    box_center, box_half = model.geom_aabb[geoms, :3], model.geom_aabb[geoms, 3:]
    centers = data.geom_xpos[geoms] + np.einsum("gij,gj->gi", rotations, box_center)
    distances = (centers - data.cam_xpos[camera]) @ world_normals.T + offsets  # (geoms, planes)
    # a box's half-extent along a normal: the sum over its axes of |normal . axis| times the half-size
    along = np.abs(np.einsum("pi,gik->gpk", world_normals, rotations))
    radii = np.einsum("gpk,gk->gp", along, box_half)
    return geoms[np.any(distances - radii > MARGIN, axis=1)]


def cullable(sim: Any) -> np.ndarray:
    """The geoms :func:`render` may leave out of ``sim``'s next off-screen render: the meshes its render context
    draws, or none when culling would not be exact (reflections or shadows drawn, a stereo view, or no geom group
    left undrawn to move them into)."""
    model, context = sim.model._model, sim._render_context_offscreen
    scene, drawn = context.scn, np.asarray(context.vopt.geomgroup) != 0
    shadows = scene.flags[SHADOW] and np.any(model.light_castshadow[model.light_active != 0])
    if scene.flags[REFLECTION] or shadows or scene.stereo or drawn.all():
        return np.empty(0, dtype=np.int64)
    return np.flatnonzero((model.geom_type == MESH) & drawn[np.clip(model.geom_group, 0, NGROUP - 1)])


def render(sim: Any, camera_name: str, width: int, height: int) -> np.ndarray:
    """``sim.render(camera_name=camera_name, width=width, height=height)`` for robosuite's ``MjSim`` ``sim`` (its
    off-screen context current), bit for bit, the meshes outside the camera's frustum (:func:`outside_frustum`) left
    out: moved for the call into a geom group its render context does not draw, then moved back. An RGB frame, as
    ``sim.render``'s, ``height`` x ``width`` x 3, bottom row first."""
    model, data = sim.model._model, sim.data._data
    geoms = cullable(sim)
    hidden = outside_frustum(model, data, sim.model.camera_name2id(camera_name), width, height, geoms)
    groups = model.geom_group[hidden]  # fancy indexing: a copy
    if len(hidden):
        model.geom_group[hidden] = np.flatnonzero(np.asarray(sim._render_context_offscreen.vopt.geomgroup) == 0)[0]
    try:
        return sim.render(camera_name=camera_name, width=width, height=height)
    finally:
        model.geom_group[hidden] = groups


__all__ = ["render", "outside_frustum", "cullable", "MARGIN"]
