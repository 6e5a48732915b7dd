"""Put a mug into LIBERO's microwave and push its door shut (LIBERO-10's "put the yellow and white mug in the microwave
and close it")."""

from __future__ import annotations

from typing import ClassVar

import numpy as np

from snapflow.envs.base import Observation
from snapflow.envs.libero_expert.fixtures import pitched_into
from snapflow.envs.libero_expert.motion import CLOSED, OPEN, REACHED, Primitive, move_action
from snapflow.envs.libero_expert.pick_and_place import CUP_GRIP_DEPTH, side_turn
from snapflow.envs.rotations import axis_angle_to_quaternion, quaternion_multiply, rotation_between

# LIBERO's microwave, in its own frame: its floor this high above its origin, its mouth facing -y, its door hinged on
# the -x side of the mouth, its control panel on the +x side
MICROWAVE_FLOOR = 0.024
# the hand's body, 7 cm thick and 10 cm tall above a mug gripped by its rim, meets the microwave's top before the mug
# is in far enough to stand on the floor: pitched this far (rad) into the mouth, fingertips leading, the body leans out
# (pitched 0.3 or 0.45, the mug was let go on the floor's edge and the door jammed on it on most of states 0-9)
MOUTH_PITCH = 0.7
# where the mug is let go (its centre, from the microwave's origin: out of the mouth, towards the control panel):
# just inside the mouth, clear of the door's side wall; the door, pushed shut, pushes it the rest of the way in
MOUTH_OUT, MOUTH_ACROSS = 0.075, -0.075
FRONT_OUT = 0.2  # the mug is carried to this far in front of the mouth (from the origin), then in, level
BACK_OUT = 0.2  # and the empty hand backs out until it is this far in front, rising
# the mug's bottom is carried this far above the microwave's floor: tilted a little in the pitched grip, carried 1.2 cm
# above, it caught the floor's front edge on 3 of states 0-9
FLOOR_GAP = 0.025
ABOVE = 0.12  # the hand comes over the rim this far above its grasp point, then down
# the door is pushed at this far from its hinge along it, the hand this far off its outer face, first standing off
# that face by DOOR_STANDOFF more and DOOR_ABOVE higher; it is shut within DOOR_SHUT rad (LIBERO's "closed": 0.005)
DOOR_PUSH_AT, DOOR_OFF, DOOR_STANDOFF, DOOR_ABOVE, DOOR_SHUT = 0.2, 0.035, 0.04, 0.12, 0.002
DOOR_LEAD = 0.03  # the hand's lead (m) past the door's face while pushing


class IntoMicrowave(Primitive):
    """Grip a mug by its rim on the side towards the microwave's control panel (the open door stands on the other
    side, in the arm's way), the hand pitched into the microwave's mouth; lift it until its bottom clears the
    microwave's floor, carry it level in front of the mouth, then in; let go and back out, rising."""

    PHASES = ("above", "descend", "close", "lift", "front", "insert", "release", "back")
    PHASE_STEPS: ClassVar[dict[str, int]] = {
        "above": 80, "descend": 40, "close": 12, "lift": 40, "front": 60, "insert": 60, "release": 8
    }  # fmt: skip

    def __init__(self, obj: str, microwave: str) -> None:
        self.obj, self.microwave = obj, microwave

    def reset(self, observation: Observation, upright: np.ndarray | None = None) -> None:
        super().reset(observation, upright)
        state = observation.privileged
        self.out = np.array([*state[f"{self.microwave}_out"][:2], 0.0])  # out of the mouth
        self.across = np.array([-self.out[1], self.out[0], 0.0])  # along the mouth, towards the control panel
        self.side = float(np.arctan2(self.across[1], self.across[0]))  # the rim's side gripped
        turned = quaternion_multiply(axis_angle_to_quaternion(np.array([0.0, 0.0, side_turn(self.side)])), self.upright)
        self.orientation = pitched_into(self.out, MOUTH_PITCH, turned)
        origin = np.asarray(state[f"{self.microwave}_pos"], dtype=float)
        self.floor = float(origin[2]) + MICROWAVE_FLOOR
        self.front = origin + self.out * FRONT_OUT + self.across * MOUTH_ACROSS
        self.target = origin + self.out * MOUTH_OUT + self.across * MOUTH_ACROSS
        self.origin, self.held, self.hanging = origin, np.zeros(3), 0.0

    def _grasp_point(self, state: dict[str, np.ndarray]) -> np.ndarray:
        centre_x, centre_y, radius, top = state[f"{self.obj}_rim"][:4]
        return np.array(
            [centre_x + radius * np.cos(self.side), centre_y + radius * np.sin(self.side), top - CUP_GRIP_DEPTH]
        )

    def act(self, observation: Observation) -> np.ndarray:
        state = observation.privileged
        hand, obj, quaternion = state["robot0_eef_pos"], state[f"{self.obj}_pos"], state["robot0_eef_quat"]
        grasp, level = self._grasp_point(state), self.floor + FLOOR_GAP + self.hanging  # the hand's carrying height
        self.timer += 1
        gripper = CLOSED
        if self.phase == "above":
            goal, gripper = grasp + np.array([0.0, 0.0, ABOVE]), OPEN
            turned = np.linalg.norm(rotation_between(quaternion, self.orientation)) < 0.1
            done = np.linalg.norm(hand - goal) < 0.02 and turned
        elif self.phase == "descend":
            goal, gripper, done = grasp, OPEN, np.linalg.norm(hand - grasp) < REACHED
        elif self.phase == "close":
            goal, done = grasp, False
            if self.timer > self.PHASE_STEPS["close"]:  # gripped: carry the mug where it sits in the hand
                self.held, self.hanging = obj - hand, float(hand[2] - state[f"{self.obj}_bottom"][0])
        elif self.phase == "lift":
            goal = np.array([*hand[:2], level + 0.01])
            done = hand[2] > level - 0.01
        elif self.phase == "front":
            goal = np.array([*(self.front - self.held)[:2], level])
            done = np.linalg.norm(hand - goal) < 0.015
        elif self.phase == "insert":
            goal = np.array([*(self.target - self.held)[:2], level])
            done = np.linalg.norm((obj - self.target)[:2]) < 0.01
        elif self.phase == "release":
            goal, gripper, done = hand.copy(), OPEN, False
        else:  # back out of the mouth, rising, to the end of the episode
            out = float((hand - self.origin) @ self.out)
            goal, gripper = hand + self.out * max(BACK_OUT + 0.02 - out, 0.0) + np.array([0.0, 0.0, 0.03]), OPEN
            done = False
        self.advance(done)
        return move_action(hand, goal, rotation_between(quaternion, self.orientation), gripper)


class CloseMicrowave(Primitive):
    """Push the microwave's open door shut: the closed fingers, the hand upright, come down off the door's outer face
    near its free end, then push into it (steering on the door's live pose) until it is shut; then the hand backs
    away. A mug left just inside the mouth is pushed the rest of the way in by the door."""

    PHASES = ("above", "descend", "push", "retreat")
    PHASE_STEPS: ClassVar[dict[str, int]] = {"above": 60, "descend": 40, "push": 200}

    def __init__(self, microwave: str) -> None:
        self.microwave = microwave

    def act(self, observation: Observation) -> np.ndarray:
        state = observation.privileged
        hand = state["robot0_eef_pos"]
        along, face = state[f"{self.microwave}_door_along"], state[f"{self.microwave}_door_face"]
        at = state[f"{self.microwave}_door_pos"] + along * DOOR_PUSH_AT + face * DOOR_OFF
        self.timer += 1
        if self.phase == "above":
            goal = at + face * DOOR_STANDOFF + np.array([0.0, 0.0, DOOR_ABOVE])
            done = np.linalg.norm(hand - goal) < 0.02
        elif self.phase == "descend":
            goal = at + face * DOOR_STANDOFF
            done = np.linalg.norm(hand - goal) < 0.01
        elif self.phase == "push":
            goal, done = at - face * DOOR_LEAD, float(state[f"{self.microwave}_door_angle"][0]) > -DOOR_SHUT
        else:  # retreat, away from the shut door, to the end of the episode
            goal, done = hand + face * 0.03 + np.array([0.0, 0.0, 0.02]), False
        self.advance(done)
        return move_action(hand, goal, rotation_between(state["robot0_eef_quat"], self.upright), CLOSED)
