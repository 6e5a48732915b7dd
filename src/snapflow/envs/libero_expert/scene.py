"""What the controllers read of a live LIBERO scene beyond robosuite's observation."""

from __future__ import annotations

from typing import Any

import numpy as np

from snapflow.envs.libero_expert.fixtures import DRAWER_HANDLES

MUGS = ("_mug",)  # open cups with a handle, gripped by the rim: their walls are read from the model
BOX_GEOM = 6  # MuJoCo's mjGEOM_BOX: LIBERO builds a mug's walls and handle of boxes
BOOKS = ("black_book",)  # one flat box: its thinnest side's direction is read (``<book>_thin_axis``, a yaw)


def privileged_extras(env: Any) -> dict[str, np.ndarray]:
    """What the controllers read beyond robosuite's observation, from the live LIBERO environment ``env``: each
    object's top and bottom above its origin (how deep to grip it, how high to release it), each fixture's position
    (the stove's knob is at its origin), each region's (a site's), each object's lowest and highest points
    (:func:`object_extent`), each mug's rim (:func:`cup_rim`), a book's thin side (:func:`thin_axis`), each drawer's
    handle and how far it is out, and a microwave's mouth and door (:func:`microwave_door`)."""
    sim, inner = env.env.sim, env.env
    extras = {}
    for name, obj in inner.objects_dict.items():
        extras[f"{name}_top_offset"] = np.array([obj.top_offset[2]])
        extras[f"{name}_bottom_offset"] = np.array([obj.bottom_offset[2]])
        extras[f"{name}_bottom"], extras[f"{name}_top"] = object_extent(sim, inner.obj_body_id[name])
        if name.startswith(BOOKS):
            extras[f"{name}_thin_axis"] = np.array([thin_axis(sim, inner.obj_body_id[name])])
        if any(kind in name for kind in MUGS):
            extras[f"{name}_rim"] = cup_rim(sim, inner.obj_body_id[name])
    for name in inner.fixtures_dict:
        extras[f"{name}_pos"] = np.array(sim.data.body_xpos[inner.obj_body_id[name]])
        for level, offset in DRAWER_HANDLES.items():
            drawer = f"{name}_cabinet_{level}"
            if drawer in sim.model.body_names:
                body = sim.model.body_name2id(drawer)
                extras[f"{name}_{level}_handle_pos"] = (
                    sim.data.body_xpos[body] + sim.data.body_xmat[body].reshape(3, 3) @ offset
                )
                # a drawer's body sits at its cabinet's origin when shut
                extras[f"{name}_{level}_drawer_out"] = sim.data.body_xpos[body] - extras[f"{name}_pos"]
        if f"{name}_microdoorroot" in sim.model.body_names:
            extras |= microwave_door(sim, name, inner.obj_body_id[name])
    for name in inner.object_sites_dict:
        extras[f"{name}_pos"] = np.array(sim.data.get_site_xpos(name))
    return extras


def microwave_door(sim: Any, name: str, body: int) -> dict[str, np.ndarray]:
    """LIBERO's microwave ``name`` (its body ``body``): the way out of its mouth (``<name>_out``, its frame's -y), its
    door's hinge (``_door_pos``, at the door's mid-height), the door's direction from the hinge to its free end
    (``_door_along``), its outer face's normal (``_door_face``) and its hinge's angle (``_door_angle``: 0 shut, down
    to -2.09 open)."""
    door = sim.model.body_name2id(f"{name}_microdoorroot")
    frame, door_frame = sim.data.body_xmat[body].reshape(3, 3), sim.data.body_xmat[door].reshape(3, 3)
    return {
        f"{name}_out": -frame[:, 1],
        f"{name}_door_pos": np.array(sim.data.body_xpos[door]),
        f"{name}_door_along": door_frame[:, 0],
        f"{name}_door_face": -door_frame[:, 1],
        f"{name}_door_angle": np.array([sim.data.get_joint_qpos(f"{name}_microjoint")]),
    }


def collision_geoms(model: Any, body: int, boxes_only: bool = False) -> np.ndarray:
    """The ids of a body's geoms that collide (LIBERO's visual meshes do not), its boxes alone with ``boxes_only``."""
    chosen = (model.geom_bodyid == body) & (model.geom_contype > 0)
    return np.flatnonzero(chosen & (model.geom_type == BOX_GEOM) if boxes_only else chosen)


def cup_rim(sim: Any, body: int) -> np.ndarray:
    """A cup's rim from its collision boxes, as ``[centre x, centre y, radius, top z, handle x, handle y]`` (the
    handle's direction from the centre, a unit vector). The walls are a ring of upright boxes reaching the top: their
    median position is the centre (the one or two handle boxes that reach as high do not move it), their median
    distance from it the radius; what stands farther out is the handle."""
    model, data = sim.model, sim.data
    boxes = collision_geoms(model, body, boxes_only=True)
    tops = data.geom_xpos[boxes, 2] + model.geom_size[boxes, 2]
    walls = boxes[tops > tops.max() - 0.01]
    centre = np.median(data.geom_xpos[walls, :2], axis=0)
    radius = float(np.median(np.linalg.norm(data.geom_xpos[walls, :2] - centre, axis=1)))
    outward = data.geom_xpos[boxes, :2] - centre
    handle = outward[np.linalg.norm(outward, axis=1) > radius + 0.01].mean(axis=0)
    return np.array([*centre, radius, tops.max(), *(handle / np.linalg.norm(handle))])


def object_extent(sim: Any, body: int) -> tuple[np.ndarray, np.ndarray]:
    """The heights of the lowest and the highest points of a body's collision geoms (their bounding boxes, turned with
    them), where LIBERO's object model gives no top of its own."""
    model, data = sim.model, sim.data
    geoms = collision_geoms(model, body)
    centre, half = model.geom_aabb[geoms, :3], model.geom_aabb[geoms, 3:]
    upward = data.geom_xmat[geoms].reshape(-1, 3, 3)[:, 2, :]  # each geom's axes' vertical components
    middles = data.geom_xpos[geoms, 2] + np.sum(upward * centre, axis=1)
    reach = np.sum(np.abs(upward) * half, axis=1)
    return np.array([(middles - reach).min()]), np.array([(middles + reach).max()])


def thin_axis(sim: Any, body: int) -> float:
    """The yaw (about the vertical) of the thinnest side of a body's first collision box: a book's thickness."""
    model, data = sim.model, sim.data
    box = collision_geoms(model, body, boxes_only=True)[0]
    axis = data.geom_xmat[box].reshape(3, 3)[:, int(np.argmin(model.geom_size[box]))]
    return float(np.arctan2(axis[1], axis[0]))
