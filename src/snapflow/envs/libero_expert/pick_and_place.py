"""Pick an object up and put it on or into a target: another object, or a fixture's surface (a site)."""

from __future__ import annotations

from collections.abc import Mapping
from typing import ClassVar

import numpy as np

from snapflow.envs.base import Observation
from snapflow.envs.libero_expert.motion import CLEARANCE, CLOSED, OPEN, REACHED, Primitive, move_action
from snapflow.envs.rotations import axis_angle_to_quaternion, quaternion_multiply, rotation_between

BOWLS = ("akita_black_bowl",)  # gripped by the rim: their tops are open
RIM_RADIUS, RIM_HEIGHT = 0.045, 0.035  # LIBERO's black bowl: its rim's radius and height above the bowl's origin
# the rim on the robot's side (-x): clear of the cabinets and boxes the Spatial scenes put behind and beside bowls
RIM_SIDE = np.pi
TOP_GRIP_DEPTH = 0.025  # fingers close this far below an object's top
# objects whose LIBERO model gives no top of its own: gripped this far below the top read from their geoms
# (``<object>_top``); the moka pot by its lid's knob, between its spout and its handle
MEASURED_GRIP_DEPTH = {"moka_pot": 0.01, "wine_bottle": 0.025, "black_book": 0.03}
# an object put upright into a slot, or into a drawer, is carried over it to within 5 mm; into a slot it is let go with
# its bottom this far above the table's level
SLOT_CARRIED, SLOT_RELEASE_GAP = 0.005, 0.03
CUP_GRIP_DEPTH = 0.02  # a cup's rim (read from the scene, ``<cup>_rim``): the fingers close this far below its top
# a cup is gripped on the side nearest the robot's (-x) that is at least this far round from its handle
HANDLE_CLEARANCE = np.deg2rad(75)
# release heights above the target's origin: a bowl lowered onto the plate, an object dropped into the basket
RELEASE_HEIGHT = {"plate": 0.03, "basket": 0.12, "akita_black_bowl": 0.08}
# how high above the target's origin the hand carries the object at least: a tall bottle carried lower catches the
# basket's handle and drags the basket away
CARRY_HEIGHT = {"basket": 0.3}
CARRIED = 0.02  # position tolerance (m) of the object over the target
# a fixture's surface (a site): the object is released with its bottom this far above it, and carried at least this
# much higher than that (over the cabinet's walls, not into them)
SITE_RELEASE_GAP, SITE_CARRY_MARGIN = 0.015, 0.06
# an object put into an open drawer goes this far from the drawer's centre towards its open end: midway between the
# drawer's front wall and the cabinet's face (a bowl has 3 mm to spare on each side)
DRAWER_PLACE_OUT = 0.023
OBSTACLE_MARGIN = 0.03  # an object carried over the others clears their tops by this much
# a bowl put into a drawer opened beside it is gripped on the rim's side facing out along the drawer's slide, where the
# hand's width (along the radius) stands clear of the open drawer, turned this far (rad) clockwise: on LIBERO-Goal's
# task 3, straight out the grip slips or tilts the bowl out of place on 3 of its 50 initial states, turned on none
RIM_OUT_TURN = -0.2


def half_turn(angle: float) -> float:
    """``angle`` modulo a half turn, in [-pi/2, pi/2): a direction the fingers close along, either way."""
    return (angle + np.pi / 2) % np.pi - np.pi / 2


def side_turn(side: float) -> float:
    """The turn of the hand about the vertical that puts its fingers (the hand's y, at yaw pi/2) across a rim gripped
    at angle ``side``: along the radius there."""
    return half_turn(side - np.pi / 2)


def cup_side(rim: np.ndarray) -> float:
    """The side of a cup's rim to grip (an angle about the vertical): the robot's (-x), or the nearest to it that is
    clear of the handle."""
    handle = np.arctan2(rim[5], rim[4])
    for offset in np.deg2rad([0, 30, -30, 60, -60, 90, -90, 120, -120]):
        side = np.pi + offset
        if abs((side - handle + np.pi) % (2 * np.pi) - np.pi) >= HANDLE_CLEARANCE:
            return float(side)
    return float(handle + np.pi)


class PickAndPlace(Primitive):
    """Rise to a travel height, move above the object, descend, close, lift, carry the object (steering on its live
    position) above the target, lower it, open, rise. Bowls are gripped by the rim with the hand turned so that the
    fingers close across it; everything else at the top centre. With ``over_others`` the object is carried clear of
    every other object's top (in a sequence, where an earlier step may have put one in the way)."""

    PHASES = ("rise", "above", "descend", "close", "lift", "carry", "lower", "release", "retreat")
    # the gripper's time to close and to open; a descent that has not arrived by then has met the object or the table
    # (grip there)
    PHASE_STEPS: ClassVar[dict[str, int]] = {
        "rise": 40, "above": 60, "descend": 40, "close": 12, "lift": 40, "carry": 80, "lower": 40, "release": 8
    }  # fmt: skip

    def __init__(
        self,
        obj: str,
        target: str,
        onto_site: bool = False,
        offset: tuple[float, float] = (0.0, 0.0),
        over_others: bool = False,
        slot_yaw: float | None = None,
        drawer: str | None = None,
        rim_out: bool = False,
    ) -> None:
        self.obj, self.target, self.onto_site, self.over_others = obj, target, onto_site, over_others
        # the target is a narrow slot: the object, gripped across its thin side, goes in with that side at this yaw
        self.slot_yaw = slot_yaw
        self.drawer = drawer  # the target is inside this open drawer (``<cabinet>_<level>``)
        self.rim_out = rim_out  # a bowl's rim is gripped on the side facing out of the drawer (RIM_OUT_TURN)
        self.offset = np.array([*offset, 0.0])  # where on the target (xy, m from its centre) the object is put
        self.release_height = next((height for kind, height in RELEASE_HEIGHT.items() if target.startswith(kind)), 0.05)
        self.carry_height = next((height for kind, height in CARRY_HEIGHT.items() if target.startswith(kind)), 0.0)
        self.rim = obj.startswith(BOWLS)
        self.side = RIM_SIDE if self.rim else None  # the rim's side gripped (an angle about the vertical)
        self.measured_depth = next((depth for kind, depth in MEASURED_GRIP_DEPTH.items() if obj.startswith(kind)), None)

    def reset(self, observation: Observation, upright: np.ndarray | None = None) -> None:
        super().reset(observation, upright)
        state = observation.privileged
        self.travel = max(state["robot0_eef_pos"][2], state[f"{self.obj}_pos"][2] + CLEARANCE)
        self.carry = max(self.travel, state[f"{self.target}_pos"][2] + self.carry_height)
        if f"{self.obj}_rim" in state:
            self.side = cup_side(state[f"{self.obj}_rim"])
        if self.rim_out and self.drawer is not None:
            out = state[f"{self.drawer}_drawer_out"]
            self.side = float(np.arctan2(out[1], out[0])) + RIM_OUT_TURN
        # the fingers close along the hand's y axis, across the rim at the side gripped: a quarter turn from it
        grip_turn = 0.0 if self.side is None else side_turn(self.side)
        self.placing_turn = grip_turn
        if f"{self.obj}_thin_axis" in state:  # the fingers (the hand's y, at yaw pi/2) close across the thin side
            grip_turn = half_turn(float(state[f"{self.obj}_thin_axis"][0]) - np.pi / 2)
            slot = grip_turn if self.slot_yaw is None else half_turn(self.slot_yaw - np.pi / 2)
            self.placing_turn = grip_turn + half_turn(slot - grip_turn)  # the shorter way round
        self.orientation = quaternion_multiply(axis_angle_to_quaternion(np.array([0.0, 0.0, grip_turn])), self.upright)
        self.placing = quaternion_multiply(
            axis_angle_to_quaternion(np.array([0.0, 0.0, self.placing_turn])), self.upright
        )
        self.floor = float(state[f"{self.obj}_bottom"][0])
        self.held = np.zeros(3)  # the object's offset from the hand once gripped
        if self.drawer is not None:
            out = state[f"{self.drawer}_drawer_out"][:2]
            self.offset[:2] = out / max(float(np.linalg.norm(out)), 1e-6) * DRAWER_PLACE_OUT
        others = [key for key in state if key.endswith("_top") and key != f"{self.obj}_top"]
        self.obstacles = max((float(state[key][0]) for key in others), default=-np.inf) if self.over_others else -np.inf
        if self.onto_site:  # the object's bottom just above the surface: its origin this high above the site
            self.release_height = SITE_RELEASE_GAP + state[f"{self.obj}_pos"][2] - float(state[f"{self.obj}_bottom"][0])

    def _grasp_point(self, state: Mapping[str, np.ndarray]) -> np.ndarray:
        position = state[f"{self.obj}_pos"]
        if f"{self.obj}_rim" in state:
            centre_x, centre_y, radius, top = state[f"{self.obj}_rim"][:4]
            rim = radius * np.array([np.cos(self.side), np.sin(self.side)])
            return np.array([centre_x + rim[0], centre_y + rim[1], top - CUP_GRIP_DEPTH])
        if self.measured_depth is not None:
            return np.array([*position[:2], state[f"{self.obj}_top"][0] - self.measured_depth])
        if self.rim:
            return position + np.array([RIM_RADIUS * np.cos(self.side), RIM_RADIUS * np.sin(self.side), RIM_HEIGHT])
        depth = max(float(state[f"{self.obj}_top_offset"][0]) - TOP_GRIP_DEPTH, -0.01)
        return position + np.array([0.0, 0.0, depth])

    def act(self, observation: Observation) -> np.ndarray:
        state = observation.privileged
        hand, obj = state["robot0_eef_pos"], state[f"{self.obj}_pos"]
        target = state[f"{self.target}_pos"] + self.offset
        grasp, over_target = self._grasp_point(state), target - self.held
        self.timer += 1
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
            if self.timer > self.PHASE_STEPS["close"]:  # gripped: carry the object where it sits in the hand
                self.held = obj - hand
                if self.onto_site:
                    self.carry = max(self.carry, target[2] + self.release_height - self.held[2] + SITE_CARRY_MARGIN)
                hanging = hand[2] - float(state[f"{self.obj}_bottom"][0])  # how far the object reaches below the hand
                self.carry = max(self.carry, self.obstacles + hanging + OBSTACLE_MARGIN)
        elif self.phase == "lift":
            goal, gripper, done = np.array([*hand[:2], self.carry]), CLOSED, hand[2] > self.carry - 0.03
        elif self.phase == "carry":
            # turning (into a slot) or tilting (a bowl gripped by its rim), the object swings round the hand: steer
            # on where it is now
            if self.slot_yaw is not None or self.rim_out:
                over_target = target - (obj - hand)
            goal, gripper = np.array([*over_target[:2], self.carry]), CLOSED
            turned = np.linalg.norm(rotation_between(state["robot0_eef_quat"], self.placing)) < 0.05
            tolerance = CARRIED if self.slot_yaw is None and self.drawer is None else SLOT_CARRIED
            done = np.linalg.norm((obj - target)[:2]) < tolerance and (turned or self.slot_yaw is None)
        elif self.phase == "lower":
            height = target[2] + self.release_height - self.held[2]
            if self.slot_yaw is not None:  # down into the slot, the object's bottom just above the table's level
                over_target = target - (obj - hand)
                height = self.floor + SLOT_RELEASE_GAP + hand[2] - float(state[f"{self.obj}_bottom"][0])
            goal, gripper = np.array([*over_target[:2], height]), CLOSED
            done = hand[2] - goal[2] < 0.01
        elif self.phase == "release":
            goal, gripper, done = hand.copy(), OPEN, False
        else:  # retreat, to the end of the episode
            goal, gripper, done = np.array([*hand[:2], self.travel]), OPEN, False
        self.advance(done)
        held = self.phase in ("lift", "carry", "lower", "release", "retreat")
        rotation = rotation_between(state["robot0_eef_quat"], self.placing if held else self.orientation)
        return move_action(hand, goal, rotation, gripper)
