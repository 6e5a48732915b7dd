"""Slide an object too flat to grip across the table into a region."""

from __future__ import annotations

from typing import ClassVar

import numpy as np

from snapflow.envs.base import Observation
from snapflow.envs.libero_expert.motion import CLEARANCE, CLOSED, Primitive, move_action
from snapflow.envs.rotations import axis_angle_to_quaternion, quaternion_multiply, rotation_between

# objects too flat to grip, dragged instead: the closed fingers set down inside the plate's rim push it from within
# (its far side is out of the arm's reach at the table's height)
PUSHED = ("plate",)
# the hand aims this far above the plate's origin: pressing on its floor, below its rim, hard enough that the noise of
# DART's collection (0.1 an action unit: 5 mm) does not lift the fingers off it and let the hand run on without the plate
# (at 0.01, 2 of 200 noisy resets succeeded; at 0.004 with the steering below, 10 of 12)
PUSH_HEIGHT = 0.004
PUSH_STEP = 0.02  # the hand's lead (m) while pushing: slowly, or the plate tips up and the fingers slide over its rim
PUSH_BEHIND = 0.02  # the fingers set down this far behind the plate's centre, away from the region
# the pushed object's centre is aimed this far past the region's centre, away from the hand: a push stops short
PUSH_OVERSHOOT = 0.015


class Push(Primitive):
    """Push an object across the table into a region: rise with the fingers closed, the hand turned broadside to the
    push, move above a point inside the object just behind its centre (on the line from the region through it),
    descend into it and drive it from within, steering on its live position (back onto the line through its centre),
    until its centre is past the region's; then rise."""

    PHASES = ("rise", "above", "descend", "push", "retreat")
    PHASE_STEPS: ClassVar[dict[str, int]] = {"rise": 40, "above": 60, "descend": 40, "push": 200}

    def __init__(self, obj: str, region: str) -> None:
        self.obj, self.region = obj, region

    def reset(self, observation: Observation, upright: np.ndarray | None = None) -> None:
        super().reset(observation, upright)
        state = observation.privileged
        self.travel = max(state["robot0_eef_pos"][2], state[f"{self.obj}_pos"][2] + CLEARANCE)
        towards = (state[f"{self.region}_pos"] - state[f"{self.obj}_pos"])[:2]
        # the fingers part along the hand's y axis (world y at the start): turn it across the push, the short way
        turn = (np.arctan2(towards[1], towards[0]) + np.pi / 2) % np.pi - np.pi / 2
        self.orientation = quaternion_multiply(axis_angle_to_quaternion(np.array([0.0, 0.0, turn])), self.upright)

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
        elif self.phase == "push":  # on towards the region (a little past its centre), by what remains of the way,
            # steering back onto the line from the region through the plate's centre when pushed off it sideways
            offset = hand[:2] - obj[:2]
            across = offset - direction * float(offset @ direction)
            goal = np.array([*(hand[:2] - across + direction * min(distance + PUSH_OVERSHOOT, PUSH_STEP)), low])
            done = distance < PUSH_OVERSHOOT
        else:  # retreat, to the end of the episode
            goal, done = np.array([*hand[:2], self.travel]), False
        self.advance(done)
        return move_action(hand, goal, rotation_between(state["robot0_eef_quat"], self.orientation), CLOSED)
