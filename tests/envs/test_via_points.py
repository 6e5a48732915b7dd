"""The multimodal via-point variant of MT10: the expert detours by a via-point first, and success needs one.

The routing logic is checked on a stub expert without the simulator; the real simulator and scripted experts (slow)
show that the variant's episodes succeed through a via-point only.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pytest

from snapflow.data.collect import collect_demonstrations
from snapflow.envs.base import Environment, Expert, Observation
from snapflow.envs.factory import make_benchmark
from snapflow.envs.metaworld import MAX_EPISODE_STEPS, STATE_DIM, MetaWorld
from snapflow.envs.via_points import (
    HANDOVER_DISTANCE,
    VIA_POINT_OFFSET,
    VIA_POINT_RADIUS,
    ViaPointExpert,
    ViaPointTracker,
    via_points,
)

EXPERT_ACTION = np.array([0.9, -0.9, 0.9, 0.4], dtype=np.float32)


@dataclass
class FixedSide:
    """Stands in for the sides generator: always the same via-point (0 left, 1 right)."""

    side: int

    def integers(self, high: int) -> int:
        assert high == 2
        return self.side


@dataclass
class StubExpert:
    """Always the same action; records the observations it was reset with."""

    resets: list[Observation] = field(default_factory=list)

    def reset(self, observation: Observation) -> None:
        self.resets.append(observation)

    def act(self, observation: Observation) -> np.ndarray:
        return EXPERT_ACTION


def at(hand: np.ndarray) -> Observation:
    """An observation whose hand (the first three state entries) is at ``hand``."""
    state = np.zeros(STATE_DIM, np.float32)
    state[:3] = hand
    return Observation(state, "reach")


def test_via_points_lie_left_and_right_of_the_hand_start():
    """The two via-points mirror the offset in x about the hand's start: left first, then right."""
    start = np.array([0.0, 0.6, 0.2], np.float32)
    left, right = via_points(start)
    assert np.allclose(right, start + VIA_POINT_OFFSET)
    assert np.allclose(left, start + VIA_POINT_OFFSET * np.array([-1, 1, 1]))


@pytest.mark.parametrize("side", [0, 1])
def test_the_expert_heads_for_the_drawn_via_point_first_then_hands_over_for_good(side: int):
    """Until the hand is within HANDOVER_DISTANCE of its via-point the expert moves the hand there (proportional,
    clipped) with the wrapped expert's gripper command; from then on, for the rest of the episode, it is the wrapped
    expert. Each reset resets the wrapped expert and starts the detour again."""
    stub = StubExpert()
    expert = ViaPointExpert(stub, FixedSide(side))
    start = np.array([0.0, 0.6, 0.2], np.float32)
    expert.reset(at(start))
    assert stub.resets[0].state[:3].tolist() == start.tolist()
    target = via_points(start)[side]
    assert np.array_equal(expert.target, target)
    direction = 1.0 if side else -1.0
    assert np.allclose(expert.act(at(start)), [direction, 0.0, 0.5, EXPERT_ACTION[3]])  # clip(10 * (+-.15, 0, .05))
    halfway = start + 0.8 * (target - start)  # 32 mm from the via-point: a slower, unclipped approach
    assert np.allclose(expert.act(at(halfway)), [*(10 * (target - halfway)), EXPERT_ACTION[3]], atol=1e-6)
    assert not expert.reached
    near = target + np.array([0.0, 0.0, 0.5 * HANDOVER_DISTANCE], np.float32)
    assert np.array_equal(expert.act(at(near)), EXPERT_ACTION) and expert.reached
    assert np.array_equal(expert.act(at(start)), EXPERT_ACTION), "the handover lasts to the end of the episode"
    expert.reset(at(start))
    assert not expert.reached and len(stub.resets) == 2
    assert not np.array_equal(expert.act(at(start)), EXPERT_ACTION)


def test_the_via_point_expert_needs_a_reset_first():
    """Acting before the first reset is a named error, not a detour to nowhere."""
    expert = MetaWorld(via_points=True).make_expert("reach-v3")
    with pytest.raises(RuntimeError, match=r"call reset\(observation\) at the start of every episode"):
        expert.act(at(np.zeros(3, np.float32)))


def test_the_benchmarks_experts_draw_sides_reproducibly_per_task():
    """Each task's expert draws its sides from a generator seeded by the task's name: the same sequence each time
    the expert is made, both sides over episodes, and another sequence for another task."""
    benchmark = MetaWorld(via_points=True)
    draws = {
        task: [benchmark.make_expert(task).sides.integers(2, size=32).tolist() for _ in range(2)]
        for task in ("reach-v3", "push-v3")
    }
    for first, second in draws.values():
        assert first == second and set(first) == {0, 1}
    assert draws["reach-v3"][0] != draws["push-v3"][0]


def test_the_tracker_counts_a_pass_within_the_radius_of_either_via_point():
    """Visited once the hand passes within VIA_POINT_RADIUS of a via-point, and for the rest of the episode."""
    tracker = ViaPointTracker()
    with pytest.raises(RuntimeError, match=r"call reset\(state\)"):
        tracker.update(at(np.zeros(3)).state)
    start = np.array([0.0, 0.6, 0.2], np.float32)
    tracker.reset(at(start).state)
    left = via_points(start)[0]
    assert not tracker.update(at(start).state)
    assert not tracker.update(at(left + np.array([1.1 * VIA_POINT_RADIUS, 0, 0], np.float32)).state)
    assert tracker.update(at(left + np.array([0.9 * VIA_POINT_RADIUS, 0, 0], np.float32)).state)
    assert tracker.update(at(start).state)
    tracker.reset(at(start).state)
    assert not tracker.visited


def test_the_tracker_keeps_the_via_point_passed_first_as_the_paths_mode():
    """The path's mode is the via-point passed first (0 left, 1 right), -1 before any; passing the other one later
    does not change it, and a reset clears it."""
    tracker = ViaPointTracker()
    start = np.array([0.0, 0.6, 0.2], np.float32)
    left, right = via_points(start)
    tracker.reset(at(start).state)
    tracker.update(at(start).state)
    assert tracker.first == -1
    tracker.update(at(right).state)
    assert tracker.first == 1
    tracker.update(at(left).state)
    assert tracker.first == 1, "the first via-point passed is the path's mode"
    tracker.reset(at(start).state)
    assert tracker.first == -1
    tracker.update(at(left).state)
    assert tracker.first == 0


def run_episode(env: Environment, expert: Expert) -> tuple[bool, int, np.ndarray]:
    """One episode on the first variation: (success, steps taken, hand positions visited)."""
    observation = env.reset(0, render=False)
    expert.reset(observation)
    hands = [observation.state[:3]]
    done = success = False
    while not done:
        observation, success, done = env.step(expert.act(observation))
        hands.append(observation.state[:3])
    return success, env.steps, np.stack(hands)


@pytest.mark.slow
@pytest.mark.parametrize("side", [0, 1])
def test_success_needs_the_task_done_after_a_via_point(side: int):
    """Simulator test: routed through either via-point the expert succeeds, passing the chosen one and not the other;
    straight to the goal it completes the task, which ends the episode but counts as a failure in the variant (and
    as a success on plain MT10)."""
    plain, variant = make_benchmark("metaworld"), make_benchmark("metaworld-via-points")
    env = variant.make_env("reach-v3", "eval")
    success, _, hands = run_episode(env, ViaPointExpert(plain.make_expert("reach-v3"), FixedSide(side)))
    assert success
    nearest = np.linalg.norm(hands[:, None, :] - via_points(hands[0])[None], axis=-1).min(0)
    assert nearest[side] < VIA_POINT_RADIUS < nearest[1 - side]
    assert env.path_mode() == side and variant.path_modes[side].startswith(("left", "right")[side])
    success, steps, _ = run_episode(env, plain.make_expert("reach-v3"))
    assert not success and steps < MAX_EPISODE_STEPS, "the episode ends at the task's success, counted as a failure"
    assert env.path_mode() == -1, "straight to the goal: neither mode"
    plain_env = plain.make_env("reach-v3", "eval")
    assert run_episode(plain_env, plain.make_expert("reach-v3"))[0]
    assert plain_env.path_mode() is None and plain.path_modes == ()


@pytest.mark.slow
def test_demonstrations_take_both_via_points_and_pass_through_the_chosen_one():
    """Simulator test: from one start the collected demonstrations set off full speed left or right, and every
    episode passes a via-point; the set records the variant's name."""
    demonstrations = collect_demonstrations(
        make_benchmark("metaworld-via-points"), ["reach-v3", "push-v3"], 6, progress=False
    )
    assert demonstrations.env == "metaworld-via-points"
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
