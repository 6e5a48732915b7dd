"""What ``snapflow bench --architecture`` can build at full size: plain Python, read by the CLI before torch loads."""

from __future__ import annotations

from snapflow.families import FAMILIES


def architectures() -> tuple[str, ...]:
    """Every family's architectures, family by family: the built-in policies, then every declared LeRobot type."""
    return tuple(name for family in FAMILIES for name in family.architectures())


__all__ = ["architectures"]
