"""The students' pre- and post-processors, found by LeRobot's factory as ``make_<type>_pre_post_processors``
when it builds them fresh (a saved student carries its own): those of the policy it was distilled from."""

from __future__ import annotations

from typing import Any

from lerobot.policies.pi0.processor_pi0 import make_pi0_pre_post_processors
from lerobot.policies.pi05.processor_pi05 import make_pi05_pre_post_processors
from lerobot.policies.smolvla.processor_smolvla import make_smolvla_pre_post_processors


def make_snapflow_smolvla_pre_post_processors(config: Any, dataset_stats: dict | None = None) -> tuple[Any, Any]:
    return make_smolvla_pre_post_processors(config, dataset_stats)


def make_snapflow_pi0_pre_post_processors(config: Any, dataset_stats: dict | None = None) -> tuple[Any, Any]:
    return make_pi0_pre_post_processors(config, dataset_stats)


def make_snapflow_pi05_pre_post_processors(config: Any, dataset_stats: dict | None = None) -> tuple[Any, Any]:
    return make_pi05_pre_post_processors(config, dataset_stats)


__all__ = [
    "make_snapflow_smolvla_pre_post_processors",
    "make_snapflow_pi0_pre_post_processors",
    "make_snapflow_pi05_pre_post_processors",
]
