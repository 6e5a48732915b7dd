"""What every LIBERO controller shares: LIBERO's action scale, the gripper's commands, and a primitive's phases."""

from __future__ import annotations

from typing import ClassVar

import numpy as np

from snapflow.envs.base import Observation

POSITION_SCALE = 0.05  # metres of target offset per unit of translation action (robosuite's OSC_POSE output_max)
ROTATION_SCALE = 0.5  # radians per unit of rotation action
OPEN, CLOSED = -1.0, 1.0
CLEARANCE = 0.12  # the hand travels this far above the object's origin, or higher if it starts higher
REACHED = 0.008  # position tolerance (m) of the hand at a grasp point
# steps a primitive spends in its last phase (rising clear) before the next primitive of a sequence takes over
SETTLED_STEPS = 15


def move_action(hand: np.ndarray, goal: np.ndarray, rotation: np.ndarray, gripper: float) -> np.ndarray:
    """The action of a P-controller towards ``goal`` turning by ``rotation`` (axis-angle), the gripper as given."""
    translation = np.clip((goal - hand) / POSITION_SCALE, -1.0, 1.0)
    return np.concatenate([translation, np.clip(rotation / ROTATION_SCALE, -1.0, 1.0), [gripper]]).astype(np.float32)


class Primitive:
    """A controller of phases run in order: each ends when its goal is reached or after its most steps (blocked
    short of its goal by a joint limit or a contact, the hand goes on from where it is); the last lasts to the end
    of the episode, or until the next primitive of a sequence takes over (:attr:`finished`)."""

    PHASES: ClassVar[tuple[str, ...]]
    PHASE_STEPS: ClassVar[dict[str, int]]

    def reset(self, observation: Observation, upright: np.ndarray | None = None) -> None:
        """Plan from the first observation of the episode (or of this primitive's turn in a sequence); the hand's
        turns are made from ``upright`` (a quaternion; default: the hand's orientation now)."""
        self.phase, self.timer = self.PHASES[0], 0
        self.upright = np.asarray(observation.privileged["robot0_eef_quat"] if upright is None else upright, float)

    def act(self, observation: Observation) -> np.ndarray:
        """The 7-D action of this step."""
        raise NotImplementedError

    def advance(self, done: bool) -> None:
        """Go on to the next phase when this one is ``done`` or has run out of steps."""
        last = self.PHASES[-1]
        if (done or self.timer > self.PHASE_STEPS.get(self.phase, np.inf)) and self.phase != last:
            self.phase, self.timer = self.PHASES[self.PHASES.index(self.phase) + 1], 0

    @property
    def finished(self) -> bool:
        """Whether the work is done and the hand has had its steps to rise clear of it."""
        return self.phase == self.PHASES[-1] and self.timer >= SETTLED_STEPS
