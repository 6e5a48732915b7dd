"""Unit quaternions (x, y, z, w, robosuite's order) and axis-angle rotations in NumPy: the LIBERO state's orientation
and its experts' steering, without a SciPy import where the CLI reads the environment registry."""

from __future__ import annotations

import numpy as np


def quaternion_to_axis_angle(quaternion: np.ndarray) -> np.ndarray:
    """Axis-angle (3,) of a unit quaternion: angle 2 acos(w) about the axis (x, y, z) / sin(angle / 2), zero for the
    identity (as robosuite's ``quat2axisangle`` and LeRobot's LIBERO processor compute it)."""
    w = float(np.clip(quaternion[3], -1.0, 1.0))
    sine = np.sqrt(1.0 - w * w)
    if np.isclose(sine, 0.0):
        return np.zeros(3, dtype=np.float32)
    return (np.asarray(quaternion[:3]) * 2.0 * np.arccos(w) / sine).astype(np.float32)


def axis_angle_to_quaternion(rotation: np.ndarray) -> np.ndarray:
    """The unit quaternion of an axis-angle rotation (its norm the angle)."""
    angle = float(np.linalg.norm(rotation))
    if np.isclose(angle, 0.0):
        return np.array([0.0, 0.0, 0.0, 1.0])
    return np.array([*(np.sin(angle / 2) * np.asarray(rotation) / angle), np.cos(angle / 2)])


def quaternion_multiply(first: np.ndarray, second: np.ndarray) -> np.ndarray:
    """The rotation ``second`` then ``first`` (Hamilton product ``first * second``)."""
    x1, y1, z1, w1 = first
    x2, y2, z2, w2 = second
    return np.array(
        [
            w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
            w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
            w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
            w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
        ]
    )


def rotation_between(current: np.ndarray, target: np.ndarray) -> np.ndarray:
    """The rotation (axis-angle, world frame, at most half a turn) that takes orientation ``current`` to
    ``target``."""
    inverse = np.array([-current[0], -current[1], -current[2], current[3]])
    difference = quaternion_multiply(target, inverse)
    if difference[3] < 0:  # q and -q are one rotation: take the shorter way round
        difference = -difference
    return quaternion_to_axis_angle(difference)


__all__ = ["quaternion_to_axis_angle", "axis_angle_to_quaternion", "quaternion_multiply", "rotation_between"]
