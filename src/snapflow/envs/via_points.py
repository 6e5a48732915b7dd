"""A multimodal variant of MT10: every task must be approached by way of one of two via-points.

MT10's scripted demonstrations are nearly unimodal, so a one-step mean predictor already does well on
them. Here each demonstration first drives the hand to one of two via-points, left or right of the hand's
start (chosen at random per episode), and only then hands over to Meta-World's scripted expert. The start
observation therefore has two valid action chunks, and their average (straight ahead) visits neither.
An episode succeeds only if the task succeeds after the hand has passed within ``VIA_POINT_RADIUS`` of
a via-point.
"""

from __future__ import annotations

from typing import Any

import numpy as np

VIA_POINT_OFFSET = np.array([0.15, 0.0, 0.05], dtype=np.float32)  # right-hand via-point, from the hand's start
VIA_POINT_RADIUS = 0.05  # how close the hand must pass for a via-point to count as visited
HANDOVER_DISTANCE = 0.02  # the expert takes over once the hand is this close to its via-point
APPROACH_GAIN = 10.0  # Meta-World's experts also use proportional position control


def hand_position(state: np.ndarray) -> np.ndarray:
    """The hand (end-effector) position: the first three entries of Meta-World's state."""
    return np.asarray(state[:3], dtype=np.float32)


def via_points(hand_start: np.ndarray) -> np.ndarray:
    """The two via-points (2, 3) of an episode whose hand starts at ``hand_start``: left, then right."""
    flip = np.array([-1.0, 1.0, 1.0], dtype=np.float32)
    return np.stack([hand_start + VIA_POINT_OFFSET * flip, hand_start + VIA_POINT_OFFSET])


class ViaPointExpert:
    """A scripted ``expert`` routed through one of the episode's two via-points, drawn at each ``reset`` from
    ``sides`` (0 left, 1 right); the expert takes over once the hand is within ``HANDOVER_DISTANCE`` of it."""

    def __init__(self, expert: Any, sides: np.random.Generator) -> None:
        self.expert = expert
        self.sides = sides
        self.target: np.ndarray | None = None
        self.reached = False

    def reset(self, observation: Any) -> None:
        self.expert.reset(observation)
        self.target = via_points(hand_position(observation.state))[int(self.sides.integers(2))]
        self.reached = False

    def act(self, observation: Any) -> np.ndarray:
        if self.target is None:
            raise RuntimeError("call reset(observation) at the start of every episode")
        action = np.asarray(self.expert.act(observation), dtype=np.float32)
        offset = self.target - hand_position(observation.state)
        self.reached = self.reached or bool(np.linalg.norm(offset) < HANDOVER_DISTANCE)
        if self.reached:
            return action
        # move the hand towards the via-point; the gripper does what the expert would do here
        return np.concatenate([np.clip(APPROACH_GAIN * offset, -1.0, 1.0), action[3:]]).astype(np.float32)


#: the two ways every task is demonstrated, in the order of :func:`via_points`, and the experts' share of each
VIA_POINT_MODES = ("left via-point", "right via-point")
VIA_POINT_MODE_WEIGHTS = (0.5, 0.5)


class ViaPointTracker:
    """Records whether the hand has passed within ``VIA_POINT_RADIUS`` of either via-point this episode, and which
    it passed first (``first``: 0 left, 1 right, -1 neither yet): the mode of the episode's path."""

    def __init__(self) -> None:
        self.points: np.ndarray | None = None
        self.first = -1

    @property
    def visited(self) -> bool:
        return self.first >= 0

    def reset(self, state: np.ndarray) -> None:
        self.points = via_points(hand_position(state))
        self.first = -1

    def update(self, state: np.ndarray) -> bool:
        if self.points is None:
            raise RuntimeError("call reset(state) at the start of every episode")
        if self.first < 0:
            distances = np.linalg.norm(self.points - hand_position(state), axis=1)
            if (distances < VIA_POINT_RADIUS).any():
                self.first = int(np.argmin(distances))
        return self.visited


__all__ = [
    "VIA_POINT_MODES",
    "VIA_POINT_MODE_WEIGHTS",
    "VIA_POINT_OFFSET",
    "VIA_POINT_RADIUS",
    "ViaPointExpert",
    "ViaPointTracker",
    "hand_position",
    "via_points",
]
