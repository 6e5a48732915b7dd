"""How long an inference delay a LeRobot policy may run under real-time chunking 'trained' in snapflow's evaluator:
a student's distillation settings, else LeRobot's own training-time RTC field, else none."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

from snapflow.adapters.lerobot.evaluation import LoadedLeRobotPolicy
from snapflow.objective.settings import DistillSettings


def _opened(config: object) -> LoadedLeRobotPolicy:
    return LoadedLeRobotPolicy(policy=None, config=config, path=Path("policy"), marker={})


def test_a_students_settings_then_lerobots_own_field_say_how_many_known_actions_it_was_trained_on():
    assert _opened(SimpleNamespace(distill=DistillSettings(rtc_max_delay=3))).known_prefix_delay == 3
    assert _opened(SimpleNamespace(distill=DistillSettings())).known_prefix_delay == 0
    assert _opened(SimpleNamespace(rtc_training_max_delay=5)).known_prefix_delay == 5
    assert _opened(SimpleNamespace()).known_prefix_delay == 0
