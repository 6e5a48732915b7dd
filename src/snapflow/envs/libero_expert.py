"""Scripted experts for LIBERO: waypoint controllers that steer by the simulator's object poses.

LIBERO ships human demonstrations only (on a hub), no expert; these controllers replace them. They read
:attr:`~snapflow.envs.base.Observation.privileged` (robosuite's object poses, plus what :func:`privileged_extras`
adds), never shown to a policy, and act through LIBERO's OSC_POSE controller: a 7-D action in [-1, 1] of translation
(1 = 5 cm of target offset), rotation (1 = 0.5 rad) and gripper (-1 open, +1 closed).

Pick-and-place covers every task of LIBERO-Spatial ("pick up the black bowl ... and place it on the plate") and
LIBERO-Object ("pick up the X and place it in the basket"), and the goals of the same form whose target is an object
(the plate, the basket, the bowl) or a fixture's surface (the stove's burner, the cabinet's top; not for the wine
bottle, whose model gives no height to grip it by). Three more primitives cover LIBERO-Goal's "open the middle drawer"
(the hand pointing into the cabinet grips the handle and pulls), "turn on the stove" (grip the knob, twist it) and
"push the plate to the front of the stove" (drag it from inside its rim). Any other goal raises :class:`NoExpertError`
naming it.
"""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from snapflow.envs.base import Observation
from snapflow.envs.rotations import axis_angle_to_quaternion, quaternion_multiply, rotation_between
from snapflow.errors import InvalidInputError

POSITION_SCALE = 0.05  # metres of target offset per unit of translation action (robosuite's OSC_POSE output_max)
ROTATION_SCALE = 0.5  # radians per unit of rotation action
OPEN, CLOSED = -1.0, 1.0
BOWLS = ("akita_black_bowl",)  # gripped by the rim: their tops are open
RIM_RADIUS, RIM_HEIGHT = 0.045, 0.035  # LIBERO's black bowl: its rim's radius and height above the bowl's origin
# the rim on the robot's side (-x): clear of the cabinets and boxes the Spatial scenes put behind and beside bowls
RIM_SIDE = np.pi
TOP_GRIP_DEPTH = 0.025  # fingers close this far below an object's top
CLEARANCE = 0.12  # the hand travels this far above the object's origin, or higher if it starts higher
# release heights above the target's origin: a bowl lowered onto the plate, an object dropped into the basket
RELEASE_HEIGHT = {"plate": 0.03, "basket": 0.12, "akita_black_bowl": 0.08}
# how high above the target's origin the hand carries the object at least: a tall bottle carried lower catches the
# basket's handle and drags the basket away
CARRY_HEIGHT = {"basket": 0.3}
PHASES = ("rise", "above", "descend", "close", "lift", "carry", "lower", "release", "retreat")
# the most steps of each phase: the gripper's time to close and to open; a descent that has not arrived by then has
# met the object or the table (grip there); a move that has not, a joint limit (go on from where the hand is)
PHASE_STEPS = {"rise": 40, "above": 60, "descend": 40, "close": 12, "lift": 40, "carry": 80, "lower": 40, "release": 8}
REACHED, CARRIED = 0.008, 0.02  # position tolerances (m): of the hand at the grasp point, of the object over the target
# a fixture's surface (a site): the object is released with its bottom this far above it, and carried at least this
# much higher than that (over the cabinet's walls, not into them)
SITE_RELEASE_GAP, SITE_CARRY_MARGIN = 0.015, 0.06
SURFACES = ("_cook_region", "_top_side")  # fixture sites an object is put on from above (not into: drawers, racks)
# objects whose model gives no top (LIBERO's default offsets): gripped at the wrong height, they are knocked over
TALL = ("wine_bottle",)
KNOB_GRIP_HEIGHT = 0.035  # the stove knob's fin: gripped this far above the stove's origin, on the knob's axis
KNOB_TURN = 1.0  # radians the hand twists the knob by (on from 0.5, its stop at 2.1)
# objects too flat to grip, dragged instead: the closed fingers set down inside the plate's rim push it from within
# (its far side is out of the arm's reach at the table's height)
PUSHED = ("plate",)
PUSH_HEIGHT = 0.01  # the hand aims this far above the plate's origin: pressing lightly on its floor, below its rim
# LIBERO's wooden cabinet: each drawer's handle bar in its drawer body's frame (the drawer slides out along -y)
DRAWER_HANDLES = {"top": (-0.00278, -0.10161, 0.18393), "middle": (-0.00278, -0.10161, 0.11041)}
DRAWER_STANDOFF = 0.1  # the hand comes level with the handle this far in front of it, then moves in
DRAWER_PULL = 0.15  # how far the handle is pulled (LIBERO's "open" from 0.14 out; the drawer's stop at 0.16)
PUSH_STEP = 0.02  # the hand's lead (m) while pushing: slowly, or the plate tips up and the fingers slide over its rim
PUSH_BEHIND = 0.02  # the fingers set down this far behind the plate's centre, away from the region
# the pushed object's centre is aimed this far past the region's centre, away from the hand: a push stops short
PUSH_OVERSHOOT = 0.015


OBJECT_NAME = r"[a-z_]+_\d+"  # an object instance of a BDDL scene (plate_1); regions and sides end otherwise


class NoExpertError(InvalidInputError):
    """No scripted controller covers this task's goal."""


class PickAndPlace:
    """Rise to a travel height, move above the object, descend, close, lift, carry the object (steering on its live
    position) above the target, lower it, open, rise. Bowls are gripped by the rim with the hand turned so that the
    fingers close across it; everything else at the top centre."""

    def __init__(self, obj: str, target: str, onto_site: bool = False) -> None:
        self.obj, self.target, self.onto_site = obj, target, onto_site
        self.release_height = next((height for kind, height in RELEASE_HEIGHT.items() if target.startswith(kind)), 0.05)
        self.carry_height = next((height for kind, height in CARRY_HEIGHT.items() if target.startswith(kind)), 0.0)
        self.rim = obj.startswith(BOWLS)
        # the fingers close along the hand's y axis, across a rim whose side is at RIM_SIDE: a quarter turn from it
        self.turn = (RIM_SIDE + np.pi) % np.pi - np.pi / 2 if self.rim else 0.0

    def reset(self, observation: Observation) -> None:
        state = observation.privileged
        self.phase, self.timer = "rise", 0
        self.travel = max(state["robot0_eef_pos"][2], state[f"{self.obj}_pos"][2] + CLEARANCE)
        self.carry = max(self.travel, state[f"{self.target}_pos"][2] + self.carry_height)
        turn = axis_angle_to_quaternion(np.array([0.0, 0.0, self.turn]))
        self.orientation = quaternion_multiply(turn, state["robot0_eef_quat"])
        self.held = np.zeros(3)  # the object's offset from the hand once gripped
        if self.onto_site:  # the object's bottom just above the surface: its origin this high above the site
            self.release_height = SITE_RELEASE_GAP - float(state[f"{self.obj}_bottom_offset"][0])

    def _grasp_point(self, state: Mapping[str, np.ndarray]) -> np.ndarray:
        position = state[f"{self.obj}_pos"]
        if self.rim:
            return position + np.array([RIM_RADIUS * np.cos(RIM_SIDE), RIM_RADIUS * np.sin(RIM_SIDE), RIM_HEIGHT])
        depth = max(float(state[f"{self.obj}_top_offset"][0]) - TOP_GRIP_DEPTH, -0.01)
        return position + np.array([0.0, 0.0, depth])

    def act(self, observation: Observation) -> np.ndarray:
        state = observation.privileged
        hand, obj, target = state["robot0_eef_pos"], state[f"{self.obj}_pos"], state[f"{self.target}_pos"]
        grasp, over_target = self._grasp_point(state), target - self.held
        self.timer += 1
        # each phase: the hand's goal, the gripper, and whether it is done (or has run out of steps: blocked short
        # of its goal by a joint limit or a contact, the hand goes on from where it is)
        if self.phase == "rise":
            turned = np.linalg.norm(rotation_between(state["robot0_eef_quat"], self.orientation)) < 0.05
            goal, gripper, done = np.array([*hand[:2], self.travel]), OPEN, abs(hand[2] - self.travel) < 0.02 and turned
        elif self.phase == "above":
            goal, gripper = np.array([*grasp[:2], self.travel]), OPEN
            done = np.linalg.norm((hand - goal)[:2]) < 0.01
        elif self.phase == "descend":
            goal, gripper, done = grasp, OPEN, np.linalg.norm(hand - grasp) < REACHED
        elif self.phase == "close":
            goal, gripper, done = grasp, CLOSED, False
        elif self.phase == "lift":
            goal, gripper, done = np.array([*hand[:2], self.carry]), CLOSED, hand[2] > self.carry - 0.03
        elif self.phase == "carry":
            goal, gripper = np.array([*over_target[:2], self.carry]), CLOSED
            done = np.linalg.norm((obj - target)[:2]) < CARRIED
        elif self.phase == "lower":
            goal, gripper = np.array([*over_target[:2], target[2] + self.release_height - self.held[2]]), CLOSED
            done = hand[2] - goal[2] < 0.01
        elif self.phase == "release":
            goal, gripper, done = hand.copy(), OPEN, False
        else:  # retreat, to the end of the episode
            goal, gripper, done = np.array([*hand[:2], self.travel]), OPEN, False
        if (done or self.timer > PHASE_STEPS.get(self.phase, np.inf)) and self.phase != "retreat":
            if self.phase == "close":
                self.held = obj - hand
                if self.onto_site:
                    self.carry = max(self.carry, target[2] + self.release_height - self.held[2] + SITE_CARRY_MARGIN)
            self.phase, self.timer = PHASES[PHASES.index(self.phase) + 1], 0
        translation = np.clip((goal - hand) / POSITION_SCALE, -1.0, 1.0)
        rotation = np.clip(rotation_between(state["robot0_eef_quat"], self.orientation) / ROTATION_SCALE, -1.0, 1.0)
        return np.concatenate([translation, rotation, [gripper]]).astype(np.float32)


def _move(hand: np.ndarray, goal: np.ndarray, rotation: np.ndarray, gripper: float) -> np.ndarray:
    """The action of a P-controller towards ``goal`` turning by ``rotation`` (axis-angle), the gripper as given."""
    translation = np.clip((goal - hand) / POSITION_SCALE, -1.0, 1.0)
    return np.concatenate([translation, np.clip(rotation / ROTATION_SCALE, -1.0, 1.0), [gripper]]).astype(np.float32)


class TurnOn:
    """Turn on a stove: rise, move above its knob, descend onto the knob's fin (the open fingers close across it:
    the hand's default orientation), grip it, twist the hand about the knob's vertical axis, open and rise."""

    PHASE_STEPS = {"rise": 40, "above": 60, "descend": 40, "close": 10, "twist": 60, "release": 8}

    def __init__(self, fixture: str) -> None:
        self.fixture = fixture

    def reset(self, observation: Observation) -> None:
        state = observation.privileged
        self.phase, self.timer = "rise", 0
        knob = state[f"{self.fixture}_pos"]
        self.grip = knob + np.array([0.0, 0.0, KNOB_GRIP_HEIGHT])
        self.travel = max(state["robot0_eef_pos"][2], self.grip[2] + CLEARANCE)
        self.orientation = np.asarray(state["robot0_eef_quat"], dtype=float)
        turn = axis_angle_to_quaternion(np.array([0.0, 0.0, KNOB_TURN]))  # counter-clockwise: the knob's "on"
        self.twisted = quaternion_multiply(turn, self.orientation)

    def act(self, observation: Observation) -> np.ndarray:
        state = observation.privileged
        hand = state["robot0_eef_pos"]
        self.timer += 1
        orientation = self.twisted if self.phase in ("twist", "release", "retreat") else self.orientation
        if self.phase == "rise":
            goal, gripper, done = np.array([*hand[:2], self.travel]), OPEN, abs(hand[2] - self.travel) < 0.02
        elif self.phase == "above":
            goal, gripper = np.array([*self.grip[:2], self.travel]), OPEN
            done = np.linalg.norm((hand - goal)[:2]) < 0.01
        elif self.phase == "descend":
            goal, gripper, done = self.grip, OPEN, np.linalg.norm(hand - self.grip) < REACHED
        elif self.phase in ("close", "twist"):
            goal, gripper = self.grip, CLOSED
            twisted = np.linalg.norm(rotation_between(state["robot0_eef_quat"], orientation)) < 0.05
            done = self.phase == "twist" and twisted
        elif self.phase == "release":
            goal, gripper, done = hand.copy(), OPEN, False
        else:  # retreat, to the end of the episode
            goal, gripper, done = np.array([*hand[:2], self.travel]), OPEN, False
        phases = ("rise", "above", "descend", "close", "twist", "release", "retreat")
        if (done or self.timer > self.PHASE_STEPS.get(self.phase, np.inf)) and self.phase != "retreat":
            self.phase, self.timer = phases[phases.index(self.phase) + 1], 0
        return _move(hand, goal, rotation_between(state["robot0_eef_quat"], orientation), gripper)


class Push:
    """Push an object across the table into a region: rise with the fingers closed, the hand turned broadside to the
    push, move above a point inside the object just behind its centre (on the line from the region through it),
    descend into it and drive it from within, steering on its live position, until its centre is past the region's;
    then rise."""

    PHASE_STEPS = {"rise": 40, "above": 60, "descend": 40, "push": 200}

    def __init__(self, obj: str, region: str) -> None:
        self.obj, self.region = obj, region

    def reset(self, observation: Observation) -> None:
        state = observation.privileged
        self.phase, self.timer = "rise", 0
        self.travel = max(state["robot0_eef_pos"][2], state[f"{self.obj}_pos"][2] + CLEARANCE)
        towards = (state[f"{self.region}_pos"] - state[f"{self.obj}_pos"])[:2]
        # the fingers part along the hand's y axis (world y at the start): turn it across the push, the short way
        turn = (np.arctan2(towards[1], towards[0]) + np.pi / 2) % np.pi - np.pi / 2
        self.orientation = quaternion_multiply(
            axis_angle_to_quaternion(np.array([0.0, 0.0, turn])), state["robot0_eef_quat"]
        )

    def act(self, observation: Observation) -> np.ndarray:
        state = observation.privileged
        hand, obj, region = state["robot0_eef_pos"], state[f"{self.obj}_pos"], state[f"{self.region}_pos"]
        towards = (region - obj)[:2]
        distance = float(np.linalg.norm(towards))
        direction = towards / max(distance, 1e-6)
        behind = obj[:2] - direction * PUSH_BEHIND
        low = obj[2] + PUSH_HEIGHT
        self.timer += 1
        if self.phase == "rise":
            turned = np.linalg.norm(rotation_between(state["robot0_eef_quat"], self.orientation)) < 0.05
            goal, done = np.array([*hand[:2], self.travel]), abs(hand[2] - self.travel) < 0.02 and turned
        elif self.phase == "above":
            goal = np.array([*behind, self.travel])
            done = np.linalg.norm((hand - goal)[:2]) < 0.01
        elif self.phase == "descend":
            goal = np.array([*behind, low])
            done = abs(hand[2] - low) < 0.01
        elif self.phase == "push":  # on towards the region (a little past its centre), by what remains of the way
            goal = np.array([*(hand[:2] + direction * min(distance + PUSH_OVERSHOOT, PUSH_STEP)), low])
            done = distance < PUSH_OVERSHOOT
        else:  # retreat, to the end of the episode
            goal, done = np.array([*hand[:2], self.travel]), False
        phases = ("rise", "above", "descend", "push", "retreat")
        if (done or self.timer > self.PHASE_STEPS.get(self.phase, np.inf)) and self.phase != "retreat":
            self.phase, self.timer = phases[phases.index(self.phase) + 1], 0
        return _move(hand, goal, rotation_between(state["robot0_eef_quat"], self.orientation), CLOSED)


class OpenDrawer:
    """Open a drawer: turn the hand to point horizontally at the cabinet (the fingers then part vertically), rise,
    come level with the handle in front of it, move in around the bar, close, pull straight out (steering on the
    handle's live position), open and back away. From above the handle cannot be reached: the drawer above's handle
    stands over it."""

    PHASE_STEPS = {"rise": 60, "front": 80, "insert": 40, "close": 12, "pull": 80, "release": 8}
    PHASES = ("rise", "front", "insert", "close", "pull", "release", "retreat")

    def __init__(self, cabinet: str, level: str) -> None:
        self.handle = f"{cabinet}_{level}_handle_pos"
        self.cabinet = f"{cabinet}_pos"

    def reset(self, observation: Observation) -> None:
        state = observation.privileged
        self.phase, self.timer = "rise", 0
        handle = state[self.handle]
        outward = (handle - state[self.cabinet])[:2]  # the handle stands out of the cabinet's front, its pull axis
        self.out = np.array([*(outward / np.linalg.norm(outward)), 0.0])
        self.start = handle.copy()
        self.travel = max(state["robot0_eef_pos"][2], handle[2] + 0.05)
        # the fingers, pointing down (-z), turned a quarter turn to point into the cabinet (-out)
        axis = np.cross([0.0, 0.0, -1.0], -self.out)
        self.orientation = quaternion_multiply(axis_angle_to_quaternion(axis * np.pi / 2), state["robot0_eef_quat"])

    def act(self, observation: Observation) -> np.ndarray:
        state = observation.privileged
        hand, handle = state["robot0_eef_pos"], state[self.handle]
        front = handle + self.out * DRAWER_STANDOFF
        self.timer += 1
        if self.phase == "rise":
            turned = np.linalg.norm(rotation_between(state["robot0_eef_quat"], self.orientation)) < 0.1
            goal = np.array([*front[:2], self.travel])
            gripper, done = OPEN, turned and np.linalg.norm(hand - goal) < 0.02
        elif self.phase == "front":
            goal, gripper, done = front, OPEN, np.linalg.norm(hand - front) < 0.01
        elif self.phase in ("insert", "close"):
            goal, gripper = handle, CLOSED if self.phase == "close" else OPEN
            done = self.phase == "insert" and np.linalg.norm(hand - handle) < REACHED
        elif self.phase == "pull":
            goal, gripper = handle + self.out * POSITION_SCALE, CLOSED
            done = float(np.dot(handle - self.start, self.out)) > DRAWER_PULL
        elif self.phase == "release":
            goal, gripper, done = hand.copy(), OPEN, False
        else:  # retreat, to the end of the episode
            goal, gripper, done = front, OPEN, False
        if (done or self.timer > self.PHASE_STEPS.get(self.phase, np.inf)) and self.phase != "retreat":
            self.phase, self.timer = self.PHASES[self.PHASES.index(self.phase) + 1], 0
        return _move(hand, goal, rotation_between(state["robot0_eef_quat"], self.orientation), gripper)


LiberoExpert = PickAndPlace | TurnOn | Push | OpenDrawer


def make_libero_expert(goal_state: Sequence[Sequence[str]]) -> LiberoExpert:
    """The controller of a LIBERO goal (its BDDL ``goal_state``), or :class:`NoExpertError` naming it."""
    if len(goal_state) == 1:
        predicate, *arguments = goal_state[0]
        drawer = re.fullmatch(r"(.+_cabinet_\d+)_(top|middle)_region", arguments[0]) if arguments else None
        if predicate == "open" and len(arguments) == 1 and drawer:
            return OpenDrawer(*drawer.groups())
        if predicate == "turnon" and len(arguments) == 1 and arguments[0].startswith("flat_stove"):
            return TurnOn(arguments[0])
        if predicate in ("on", "in") and len(arguments) == 2 and re.fullmatch(OBJECT_NAME, arguments[0]):
            obj, target = arguments
            target = target.removesuffix("_contain_region")  # "in the basket": over the basket itself
            if re.fullmatch(OBJECT_NAME, target):
                return PickAndPlace(obj, target)
            if target.endswith(SURFACES) and not obj.startswith(TALL):  # a fixture's surface (a site): from the extras
                return PickAndPlace(obj, target, onto_site=True)
            if target.startswith("main_table_") and obj.startswith(PUSHED):  # a region of the table: slide it there
                return Push(obj, target)
    raise NoExpertError(f"no scripted controller covers the goal {[list(predicate) for predicate in goal_state]}")


def privileged_extras(env: Any) -> dict[str, np.ndarray]:
    """What the controllers read beyond robosuite's observation, from the live LIBERO environment ``env``: each
    object's top and bottom above its origin (how deep to grip it, how high to release it), each fixture's position
    (the stove's knob is at its origin) and each region's (a site's)."""
    sim, inner = env.env.sim, env.env
    extras = {}
    for name, obj in inner.objects_dict.items():
        extras[f"{name}_top_offset"] = np.array([obj.top_offset[2]])
        extras[f"{name}_bottom_offset"] = np.array([obj.bottom_offset[2]])
    for name in inner.fixtures_dict:
        extras[f"{name}_pos"] = np.array(sim.data.body_xpos[inner.obj_body_id[name]])
        for level, offset in DRAWER_HANDLES.items():
            drawer = f"{name}_cabinet_{level}"
            if drawer in sim.model.body_names:
                body = sim.model.body_name2id(drawer)
                extras[f"{name}_{level}_handle_pos"] = (
                    sim.data.body_xpos[body] + sim.data.body_xmat[body].reshape(3, 3) @ offset
                )
    for name in inner.object_sites_dict:
        extras[f"{name}_pos"] = np.array(sim.data.get_site_xpos(name))
    return extras


__all__ = [
    "LiberoExpert",
    "NoExpertError",
    "OpenDrawer",
    "PickAndPlace",
    "Push",
    "TurnOn",
    "make_libero_expert",
    "privileged_extras",
]
