"""What ``snapflow bench --architecture`` can build at full size: plain Python, read by the CLI before torch loads."""

from __future__ import annotations

from snapflow.adapters.lerobot_types import LEROBOT_POLICY_TYPES
from snapflow.policies.factory import POLICIES


def architectures() -> tuple[str, ...]:
    """Every built-in policy, then every declared LeRobot type."""
    return (*POLICIES, *LEROBOT_POLICY_TYPES)


__all__ = ["architectures"]
