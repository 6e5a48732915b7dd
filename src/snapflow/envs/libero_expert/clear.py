"""Drag an object out of the way of a drawer about to be opened."""

from __future__ import annotations

from typing import ClassVar

import numpy as np

from snapflow.envs.base import Observation
from snapflow.envs.libero_expert.motion import CLEARANCE, CLOSED, Primitive, move_action
from snapflow.envs.rotations import rotation_between

# the closed fingers hang this far above the object's origin: inside a bowl, just above its floor, below its rim
DRAG_HEIGHT = 0.02
DRAG_BEHIND = 0.02  # they set down this far behind the object's centre, away from where it is dragged
DRAG_STEP = 0.03  # the hand's lead (m) while dragging
DRAG_DISTANCE = 0.06  # how far the object is dragged
ABOVE_HEIGHT = 0.09  # the hand comes over the object this high above its origin (clear of a bowl's rim), then down


def unit(vector: np.ndarray) -> np.ndarray:
    """``vector`` scaled to length 1 (a zero vector stays zero)."""
    return vector / max(float(np.linalg.norm(vector)), 1e-6)


class ClearDrawer(Primitive):
    """Drag an object standing beside a shut drawer out of its way: the open drawer would stand over it, 1-2 cm from
    every grip of a bowl's rim (LIBERO-Goal's task 3). The closed fingers come down inside the object just behind its
    centre and drive it from within, diagonally away from the cabinet's side and out along the drawer's slide, where
    its rim on the side facing out can be gripped clear of the drawer; then the hand rises."""

    PHASES = ("above", "descend", "drag", "retreat")
    PHASE_STEPS: ClassVar[dict[str, int]] = {"above": 60, "descend": 30, "drag": 40}

    def __init__(self, obj: str, cabinet: str, level: str) -> None:
        self.obj, self.cabinet, self.handle = obj, f"{cabinet}_pos", f"{cabinet}_{level}_handle_pos"

    def reset(self, observation: Observation, upright: np.ndarray | None = None) -> None:
        super().reset(observation, upright)
        state = observation.privileged
        cabinet, self.start = state[self.cabinet][:2], np.array(state[f"{self.obj}_pos"], dtype=float)
        out = unit(state[self.handle][:2] - cabinet)  # the way the drawer slides out
        beside = self.start[:2] - cabinet
        self.direction = unit(unit(beside - (beside @ out) * out) + out)  # halfway between sideways and out

    def act(self, observation: Observation) -> np.ndarray:
        state = observation.privileged
        hand, obj = state["robot0_eef_pos"], state[f"{self.obj}_pos"]
        behind = obj[:2] - self.direction * DRAG_BEHIND
        self.timer += 1
        if self.phase == "above":
            goal = np.array([*behind, obj[2] + ABOVE_HEIGHT])
            done = np.linalg.norm((hand - goal)[:2]) < 0.015 and abs(hand[2] - goal[2]) < 0.03
        elif self.phase == "descend":
            goal = np.array([*behind, obj[2] + DRAG_HEIGHT])
            done = abs(hand[2] - goal[2]) < 0.01
        elif self.phase == "drag":
            goal = np.array([*(hand[:2] + self.direction * DRAG_STEP), obj[2] + DRAG_HEIGHT])
            done = float((obj - self.start)[:2] @ self.direction) > DRAG_DISTANCE
        else:  # retreat, out of the object, to the end of the episode
            goal, done = np.array([*hand[:2], self.start[2] + CLEARANCE]), False
        self.advance(done)
        return move_action(hand, goal, rotation_between(state["robot0_eef_quat"], self.upright), CLOSED)
