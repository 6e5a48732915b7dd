"""Scripted experts for LIBERO: waypoint controllers that steer by the simulator's object poses.

LIBERO ships human demonstrations only (on a hub), no expert; these controllers replace them. They read
:attr:`~snapflow.envs.base.Observation.privileged` (robosuite's object poses, plus what :func:`privileged_extras`
adds), never shown to a policy, and act through LIBERO's OSC_POSE controller: a 7-D action in [-1, 1] of translation
(1 = 5 cm of target offset), rotation (1 = 0.5 rad) and gripper (-1 open, +1 closed).

One controller, pick-and-place, covers every task of LIBERO-Spatial ("pick up the black bowl ... and place it on the
plate") and LIBERO-Object ("pick up the X and place it in the basket"), and the LIBERO-Goal and LIBERO-10 goals of
the same form whose target is an object (the plate, the basket, the bowl); any other goal raises
:class:`NoExpertError` naming it.
"""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from snapflow.envs.base import Observation
from snapflow.envs.rotations import axis_angle_to_quaternion, quaternion_multiply, rotation_between

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


OBJECT_NAME = r"[a-z_]+_\d+"  # an object instance of a BDDL scene (plate_1); regions and sides end otherwise


class NoExpertError(ValueError):
    """No scripted controller covers this task's goal."""


class PickAndPlace:
    """Rise to a travel height, move above the object, descend, close, lift, carry the object (steering on its live
    position) above the target, lower it, open, rise. Bowls are gripped by the rim with the hand turned so that the
    fingers close across it; everything else at the top centre."""

    def __init__(self, obj: str, target: str) -> None:
        self.obj, self.target = obj, target
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
            self.phase, self.timer = PHASES[PHASES.index(self.phase) + 1], 0
        translation = np.clip((goal - hand) / POSITION_SCALE, -1.0, 1.0)
        rotation = np.clip(rotation_between(state["robot0_eef_quat"], self.orientation) / ROTATION_SCALE, -1.0, 1.0)
        return np.concatenate([translation, rotation, [gripper]]).astype(np.float32)


def make_libero_expert(goal_state: Sequence[Sequence[str]]) -> PickAndPlace:
    """The controller of a LIBERO goal (its BDDL ``goal_state``), or :class:`NoExpertError` naming it."""
    if len(goal_state) == 1 and len(goal_state[0]) == 3 and goal_state[0][0] in ("on", "in"):
        _, obj, target = goal_state[0]
        target = target.removesuffix("_contain_region")  # "in the basket": over the basket itself
        if re.fullmatch(OBJECT_NAME, obj) and re.fullmatch(OBJECT_NAME, target):  # not a region of a fixture
            return PickAndPlace(obj, target)
    raise NoExpertError(f"no scripted controller covers the goal {[list(predicate) for predicate in goal_state]}")


def privileged_extras(env: Any) -> dict[str, np.ndarray]:
    """What the controllers read beyond robosuite's observation: each object's top above its origin (how deep to
    grip it), from the live LIBERO environment ``env``."""
    return {f"{name}_top_offset": np.array([obj.top_offset[2]]) for name, obj in env.env.objects_dict.items()}


__all__ = ["NoExpertError", "PickAndPlace", "make_libero_expert", "privileged_extras"]
