"""The jump and jerk at chunk switches, by hand."""

from __future__ import annotations

import math

import numpy as np
import pytest

from snapflow.errors import InvalidInputError
from snapflow.evaluation.switches import SwitchSmoothness, mean_smoothness, switch_smoothness, switch_steps


def test_switches_are_every_n_act_steps_after_the_first_chunk():
    assert switch_steps(10, 4) == [4, 8] and switch_steps(4, 4) == [] and switch_steps(9, 3) == [3, 6]
    with pytest.raises(InvalidInputError):
        switch_steps(5, 0)


def test_a_step_at_each_switch_is_measured_there_and_nowhere_else():
    # a ramp of slope 1 (no jerk) with a jump of 2 added from each switch on: actions 0,1,2,3 | 6,7,8,9 | 12,13
    steps = np.arange(10.0)
    actions = (steps + 2.0 * (steps // 4))[:, None]
    measured = switch_smoothness(actions, 4)
    assert measured.switches == 2
    assert measured.jump_at_switches == pytest.approx(3.0) and measured.jump_elsewhere == pytest.approx(1.0)
    # third differences d_{k+1} - 2 d_k + d_{k-1} of the steps d = 1,1,1,3,1,1,1,3,1: 4 across each switch's step,
    # 0 or 2 at the other steps (2 where the step of 3 is one of the three)
    assert measured.jerk_at_switches == pytest.approx(4.0)
    assert measured.jerk_elsewhere == pytest.approx((0 + 2 + 2 + 0 + 2) / 5)
    smooth = switch_smoothness(np.stack([np.sin(steps / 3), np.cos(steps / 3)], axis=1), 4)
    assert smooth.jump_at_switches == pytest.approx(smooth.jump_elsewhere, rel=0.2)
    assert math.isnan(switch_smoothness(actions[:4], 4).jump_at_switches), "no switch, no mean"


def test_episodes_smoothness_averages_each_measure_over_the_episodes_that_have_it():
    first = SwitchSmoothness(2, 1.0, 0.5, 4.0, math.nan)
    second = SwitchSmoothness(1, 3.0, 1.5, 2.0, 1.0)
    assert mean_smoothness([first, second]) == SwitchSmoothness(3, 2.0, 1.0, 3.0, 1.0)
    assert first.to_dict()["jerk_elsewhere"] is None and math.isnan(
        SwitchSmoothness.from_dict(first.to_dict()).jerk_elsewhere
    )
