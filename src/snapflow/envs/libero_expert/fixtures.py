"""Work a fixture's joint: twist a stove's knob, pull a drawer open, push one shut."""

from __future__ import annotations

from typing import ClassVar

import numpy as np

from snapflow.envs.base import Observation
from snapflow.envs.libero_expert.motion import (
    CLEARANCE,
    CLOSED,
    OPEN,
    POSITION_SCALE,
    REACHED,
    Primitive,
    move_action,
)
from snapflow.envs.libero_expert.pick_and_place import half_turn
from snapflow.envs.rotations import axis_angle_to_quaternion, quaternion_multiply, rotation_between

KNOB_GRIP_HEIGHT = 0.035  # the stove knob's fin: gripped this far above the stove's origin, on the knob's axis
KNOB_TURN = 1.0  # radians the hand twists the knob by (on from 0.5, its stop at 2.1)
# LIBERO's wooden cabinet: each drawer's handle bar in its drawer body's frame (the drawer slides out along -y)
DRAWER_HANDLES = {
    "top": (-0.00278, -0.10161, 0.18393),
    "middle": (-0.00278, -0.10161, 0.11041),
    "bottom": (-0.00278, -0.10161, 0.0411),
}
DRAWER_STANDOFF = 0.1  # the hand comes level with the handle this far in front of it, then moves in
DRAWER_PULL = 0.15  # how far the handle is pulled (LIBERO's "open" from 0.14 out; the drawer's stop at 0.16)
DRAWER_SHUT = 0.002  # a drawer is pushed until it is this close to shut (LIBERO's "closed": 0 out)
# the hand pushing a drawer shut points down and this far (rad) into the cabinet: its fingertips reach a bottom
# drawer's face while its forearm stays clear of the cabinet's top (pointing down, the forearm meets the top with the
# drawer 7 cm out; pointing in, the hand's width keeps it 10 cm above the handle, on the drawer above)
DRAWER_PUSH_PITCH = 0.8


def pitched_into(out: np.ndarray, pitch: float, upright: np.ndarray) -> np.ndarray:
    """The hand's orientation with its fingers turned by ``pitch`` (rad) from pointing down (-z) towards a cabinet
    whose front faces ``out``: a quarter turn points them straight into it."""
    axis = np.cross([0.0, 0.0, -1.0], -out)
    return quaternion_multiply(axis_angle_to_quaternion(axis * pitch), upright)


class TurnOn(Primitive):
    """Turn on a stove: rise, move above its knob, descend onto the knob's fin (the open fingers close across it:
    the hand's default orientation), grip it, twist the hand about the knob's vertical axis, open and rise."""

    PHASES = ("rise", "above", "descend", "close", "twist", "release", "retreat")
    PHASE_STEPS: ClassVar[dict[str, int]] = {
        "rise": 40, "above": 60, "descend": 40, "close": 10, "twist": 60, "release": 8
    }  # fmt: skip

    def __init__(self, fixture: str) -> None:
        self.fixture = fixture

    def reset(self, observation: Observation, upright: np.ndarray | None = None) -> None:
        super().reset(observation, upright)
        state = observation.privileged
        knob = state[f"{self.fixture}_pos"]
        self.grip = knob + np.array([0.0, 0.0, KNOB_GRIP_HEIGHT])
        self.travel = max(state["robot0_eef_pos"][2], self.grip[2] + CLEARANCE)
        self.orientation = self.upright
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
        self.advance(done)
        return move_action(hand, goal, rotation_between(state["robot0_eef_quat"], orientation), gripper)


class DrawerPrimitive(Primitive):
    """What opening and shutting a drawer share: its handle, the direction it slides out, and the approach: turn the
    hand pitched towards the cabinet while rising to a travel height in front of the handle, then come level with it
    there. A subclass gives the gripper during the approach and the phases at the handle (:meth:`_at_handle`)."""

    APPROACH_GRIPPER: ClassVar[float]

    def __init__(self, cabinet: str, level: str) -> None:
        self.handle = f"{cabinet}_{level}_handle_pos"

    def _face(self, state: dict[str, np.ndarray], out: np.ndarray, pitch: float) -> None:
        """Plan the approach to a drawer sliding out along ``out`` (xy), the hand pitched by ``pitch`` (rad)."""
        self.out = np.array([*(out[:2] / max(float(np.linalg.norm(out[:2])), 1e-6)), 0.0])
        self.travel = max(state["robot0_eef_pos"][2], state[self.handle][2] + 0.05)
        self.orientation = pitched_into(self.out, pitch, self.upright)

    def _approach(self, state: dict[str, np.ndarray], front: np.ndarray) -> tuple[np.ndarray, bool]:
        """The goal of the ``rise`` or ``front`` phase, and whether it is reached."""
        hand = state["robot0_eef_pos"]
        if self.phase == "rise":
            turned = np.linalg.norm(rotation_between(state["robot0_eef_quat"], self.orientation)) < 0.1
            goal = np.array([*front[:2], self.travel])
            return goal, bool(turned and np.linalg.norm(hand - goal) < 0.02)
        return front, bool(np.linalg.norm(hand - front) < 0.01)

    def _at_handle(
        self, state: dict[str, np.ndarray], handle: np.ndarray, front: np.ndarray
    ) -> tuple[np.ndarray, float, bool]:
        """The goal, the gripper and whether the phase is done, in the phases after the approach."""
        raise NotImplementedError

    def act(self, observation: Observation) -> np.ndarray:
        state = observation.privileged
        hand, handle = state["robot0_eef_pos"], state[self.handle]
        front = handle + self.out * DRAWER_STANDOFF
        self.timer += 1
        if self.phase in ("rise", "front"):
            (goal, done), gripper = self._approach(state, front), self.APPROACH_GRIPPER
        else:
            goal, gripper, done = self._at_handle(state, handle, front)
        self.advance(done)
        return move_action(hand, goal, rotation_between(state["robot0_eef_quat"], self.orientation), gripper)


class OpenDrawer(DrawerPrimitive):
    """Open a drawer: turn the hand to point horizontally at the cabinet (the fingers then part vertically), rise,
    come level with the handle in front of it, move in around the bar, close, pull straight out (steering on the
    handle's live position), open and back away. From above the handle cannot be reached: the drawer above's handle
    stands over it."""

    PHASES = ("rise", "front", "insert", "close", "pull", "release", "retreat")
    APPROACH_GRIPPER = OPEN  # open, to close round the handle's bar
    PHASE_STEPS: ClassVar[dict[str, int]] = {
        "rise": 60, "front": 80, "insert": 40, "close": 12, "pull": 80, "release": 8
    }  # fmt: skip

    def __init__(self, cabinet: str, level: str) -> None:
        super().__init__(cabinet, level)
        self.cabinet = f"{cabinet}_pos"

    def reset(self, observation: Observation, upright: np.ndarray | None = None) -> None:
        super().reset(observation, upright)
        state = observation.privileged
        self.start = state[self.handle].copy()
        # the handle stands out of the cabinet's front, its pull axis; the fingers point into the cabinet
        self._face(state, self.start - state[self.cabinet], np.pi / 2)

    def _at_handle(
        self, state: dict[str, np.ndarray], handle: np.ndarray, front: np.ndarray
    ) -> tuple[np.ndarray, float, bool]:
        hand = state["robot0_eef_pos"]
        if self.phase in ("insert", "close"):
            done = self.phase == "insert" and np.linalg.norm(hand - handle) < REACHED
            return handle, CLOSED if self.phase == "close" else OPEN, done
        if self.phase == "pull":
            return (
                handle + self.out * POSITION_SCALE,
                CLOSED,
                float(np.dot(handle - self.start, self.out)) > DRAWER_PULL,
            )
        if self.phase == "release":
            return hand.copy(), OPEN, False
        return front, OPEN, False  # retreat, to the end of the episode


# a top drawer is opened from above (nothing stands over its handle): the hand, upright, its fingers parting along the
# drawer's slide, centres this far out from the handle's bar, so that its inner finger (thick higher up) clears the
# cabinet's top and comes down between the bar and the drawer's face; it comes over that point this high first
TOP_GRIP_OUT, TOP_GRIP_ABOVE = 0.04, 0.05


class OpenTopDrawer(Primitive):
    """Open a top drawer from above, the hand upright: come over the handle's bar with the fingers parting along the
    drawer's slide, descend round the bar, close, pull straight out (steering on the handle's live position), open
    and rise clear. Unlike :class:`OpenDrawer` it does not turn the hand to point into the cabinet, so it ends as the
    next primitive of a sequence starts, upright."""

    PHASES = ("above", "descend", "close", "pull", "release", "retreat")
    # the descent meets the drawer's face 1.7 cm above the bar's centre, the fingers round the bar: grip there
    PHASE_STEPS: ClassVar[dict[str, int]] = {
        "above": 60, "descend": 25, "close": 8, "pull": 40, "release": 6
    }  # fmt: skip

    def __init__(self, cabinet: str, level: str) -> None:
        self.cabinet, self.handle = f"{cabinet}_pos", f"{cabinet}_{level}_handle_pos"

    def reset(self, observation: Observation, upright: np.ndarray | None = None) -> None:
        super().reset(observation, upright)
        state = observation.privileged
        self.start = np.array(state[self.handle], dtype=float)
        out = (self.start - state[self.cabinet])[:2]
        self.out = np.array([*(out / max(float(np.linalg.norm(out)), 1e-6)), 0.0])
        # upright, the fingers part along the hand's y axis (world y at yaw 0): turn it along the slide
        turn = half_turn(float(np.arctan2(self.out[1], self.out[0])) - np.pi / 2)
        self.orientation = quaternion_multiply(axis_angle_to_quaternion(np.array([0.0, 0.0, turn])), self.upright)

    def act(self, observation: Observation) -> np.ndarray:
        state = observation.privileged
        hand, handle = state["robot0_eef_pos"], state[self.handle]
        grip = handle + self.out * TOP_GRIP_OUT
        self.timer += 1
        if self.phase == "above":
            goal, gripper = grip + np.array([0.0, 0.0, TOP_GRIP_ABOVE]), OPEN
            done = np.linalg.norm(hand - goal) < 0.015
        elif self.phase in ("descend", "close"):
            goal, gripper = grip, OPEN if self.phase == "descend" else CLOSED
            done = self.phase == "descend" and np.linalg.norm(hand - grip) < REACHED
        elif self.phase == "pull":
            goal, gripper = grip + self.out * POSITION_SCALE, CLOSED
            done = float(np.dot(handle - self.start, self.out)) > DRAWER_PULL
        elif self.phase == "release":
            goal, gripper, done = hand.copy(), OPEN, False
        else:  # retreat, up off the bar, to the end of the episode
            goal, gripper, done = np.array([*hand[:2], grip[2] + TOP_GRIP_ABOVE]), OPEN, False
        self.advance(done)
        return move_action(hand, goal, rotation_between(state["robot0_eef_quat"], self.orientation), gripper)


class CloseDrawer(DrawerPrimitive):
    """Close an open drawer: the closed fingers, the hand pitched into the cabinet, come level with the handle in front
    of it and push it in along its slide (steering on the handle's live position) until the drawer is shut; then the
    hand backs away."""

    PHASES = ("rise", "front", "push", "retreat")
    APPROACH_GRIPPER = CLOSED  # the closed fingers push on the handle
    PHASE_STEPS: ClassVar[dict[str, int]] = {"rise": 60, "front": 80, "push": 150}

    def __init__(self, cabinet: str, level: str) -> None:
        super().__init__(cabinet, level)
        self.drawer = f"{cabinet}_{level}_drawer_out"  # the drawer's offset from where it sits shut

    def reset(self, observation: Observation, upright: np.ndarray | None = None) -> None:
        super().reset(observation, upright)
        state = observation.privileged
        self._face(state, state[self.drawer], DRAWER_PUSH_PITCH)

    def _at_handle(
        self, state: dict[str, np.ndarray], handle: np.ndarray, front: np.ndarray
    ) -> tuple[np.ndarray, float, bool]:
        if self.phase == "push":  # a full step past the handle, which the fingers lean on
            shut = float(np.dot(state[self.drawer], self.out)) < DRAWER_SHUT
            return handle - self.out * POSITION_SCALE, CLOSED, shut
        return front, CLOSED, False  # retreat, to the end of the episode
