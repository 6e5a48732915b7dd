"""What ``snapflow bench --architecture`` can build at full size: plain Python, read by the CLI before torch loads."""

from __future__ import annotations

from snapflow.policies.factory import POLICIES

LEROBOT_ARCHITECTURES = ("pi0", "pi05", "smolvla")


def architectures() -> tuple[str, ...]:
    """Every built-in policy, then LeRobot's."""
    return (*POLICIES, *LEROBOT_ARCHITECTURES)


__all__ = ["LEROBOT_ARCHITECTURES", "architectures"]
