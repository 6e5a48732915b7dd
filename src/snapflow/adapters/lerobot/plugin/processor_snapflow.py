"""The students' pre- and post-processors, found by LeRobot's factory as ``make_<type>_pre_post_processors``
when it builds them fresh (a saved student carries its own): those of the policy it was distilled from, which LeRobot
keeps beside its policy class (``processor_<type>.make_<type>_pre_post_processors``)."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from snapflow._lazy import resolve
from snapflow.adapters.lerobot_types import installed_lerobot_types, lerobot_policy_type


def student_processors(base_type: str) -> Callable[..., tuple[Any, Any]]:
    """``make_snapflow_<type>_pre_post_processors`` of the declared type ``base_type``, made on first use."""
    declared = lerobot_policy_type(base_type)
    name = f"make_{declared.student_type}_pre_post_processors"
    if name not in globals():
        module = declared.policy.partition(":")[0].replace(".modeling_", ".processor_")

        def make(config: Any, dataset_stats: dict | None = None) -> tuple[Any, Any]:
            return resolve(f"{module}:make_{base_type}_pre_post_processors")(config, dataset_stats)

        make.__name__ = make.__qualname__ = name
        globals()[name] = make
    return globals()[name]


for _declared in installed_lerobot_types():
    student_processors(_declared)


__all__ = ["student_processors"]
