"""The multimodal via-point variant of MT10, against the real simulator and scripted experts."""

from __future__ import annotations

import numpy as np
import pytest

from snapflow.data.collect import collect_demonstrations
from snapflow.envs.metaworld import MetaWorldEnv, make_expert
from snapflow.envs.via_points import VIA_POINT_RADIUS, ViaPointExpert, via_points


def test_demonstrations_take_both_via_points_and_pass_through_the_chosen_one():
    demonstrations = collect_demonstrations(["reach-v3", "push-v3"], 6, progress=False, via_points=True)
    for task in ("reach-v3", "push-v3"):
        episodes = [episode for episode in demonstrations.episodes if episode.task == task]
        first_actions = np.stack([demonstrations.actions[episode.start] for episode in episodes])
        # one start, two valid first actions: full speed left or right
        assert set(np.sign(first_actions[:, 0])) == {-1.0, 1.0}
        for episode in episodes:
            hands = demonstrations.states[episode.start : episode.start + episode.length, :3]
            points = via_points(hands[0])
            nearest = np.linalg.norm(hands[:, None, :] - points[None], axis=-1).min(0)
            assert nearest.min() < VIA_POINT_RADIUS  # each episode visited one of the two


def run_episode(env: MetaWorldEnv, expert, side: int | None = None) -> tuple[bool, int]:
    observation = env.reset(0, render=False)
    if side is not None:
        expert.reset(observation.state, side)
    done = success = False
    while not done:
        observation, success, done = env.step(expert.get_action(observation.state))
    return success, env.steps


@pytest.mark.parametrize("side", [0, 1])
def test_success_needs_the_task_done_after_a_via_point(side):
    env = MetaWorldEnv("reach-v3", "eval", via_points=True)
    assert run_episode(env, ViaPointExpert(make_expert("reach-v3")), side)[0]
    success, steps = run_episode(env, make_expert("reach-v3"))  # straight to the goal: the task succeeds, the variant does not
    assert not success and steps < 500, "the episode ends at the task's success, counted as a failure"
    plain = MetaWorldEnv("reach-v3", "eval")
    assert run_episode(plain, make_expert("reach-v3"))[0]


def test_the_via_point_expert_needs_a_reset_first():
    with pytest.raises(RuntimeError, match="reset"):
        ViaPointExpert(make_expert("reach-v3")).get_action(np.zeros(39))
