"""The LIBERO experts' parts: the grip on a cup's rim, objects sharing a surface, sequences of primitives, and the
scene geometry they read, checked by hand and on the real simulator."""

from __future__ import annotations

from typing import ClassVar

import numpy as np
import pytest

from snapflow.envs.base import Observation
from snapflow.envs.libero_expert import InSequence, PickAndPlace, TurnOn, make_libero_expert
from snapflow.envs.libero_expert.clear import ClearDrawer
from snapflow.envs.libero_expert.fixtures import OpenTopDrawer
from snapflow.envs.libero_expert.goals import SHARED_SURFACE_SPACING
from snapflow.envs.libero_expert.motion import SETTLED_STEPS, Primitive
from snapflow.envs.libero_expert.pick_and_place import RIM_OUT_TURN, cup_side, half_turn, side_turn


def test_a_cup_is_gripped_on_the_robots_side_unless_its_handle_is_there():
    """Sides are angles about the vertical: the robot's is pi (-x). A handle at +y (pi/2) is 90 degrees from it:
    grip there. A handle at -x (pi) rules out every side within 75 degrees of it: pi, pi +- 30 and pi +- 60 degrees;
    the first clear one tried is pi + 90 degrees (-y). The hand turns a quarter turn from the side gripped."""
    rim = lambda handle: np.array([0.0, 0.0, 0.04, 0.1, np.cos(handle), np.sin(handle)])  # noqa: E731
    assert cup_side(rim(np.pi / 2)) == pytest.approx(np.pi)
    assert cup_side(rim(np.pi)) == pytest.approx(1.5 * np.pi)
    assert cup_side(rim(0.0)) == pytest.approx(np.pi)
    assert side_turn(np.pi) == pytest.approx(-np.pi / 2)  # the bowls' turn, as before cups had a rim of their own
    assert side_turn(1.5 * np.pi) == pytest.approx(0.0)


def test_a_direction_the_fingers_close_along_is_taken_modulo_a_half_turn():
    """The fingers close along the hand's y axis, either way: a thin side at yaw 0.865 (LIBERO-10 task 5's book) is
    met by turning the hand 0.865 - pi/2 = -0.706 rad; a slot along x (yaw 0) then wants -pi/2, which is the same
    direction as +pi/2: the shorter way from -0.706 is -pi/2 (0.865 rad more), not +pi/2."""
    assert half_turn(np.pi) == pytest.approx(0.0) and half_turn(0.3) == pytest.approx(0.3)
    assert half_turn(0.865 - np.pi / 2) == pytest.approx(-0.706, abs=1e-3)
    grip = half_turn(0.865 - np.pi / 2)
    assert grip + half_turn(half_turn(0.0 - np.pi / 2) - grip) == pytest.approx(-np.pi / 2)


def test_objects_put_on_one_surface_stand_side_by_side_and_are_carried_over_the_others():
    """LIBERO-10's "put both moka pots on the stove": each pot goes 4.5 cm from the burner's centre along x (the
    first the farther), both inside its 7.5 cm half-width; a goal of one predicate keeps the centre and the plain
    carry height."""
    both = make_libero_expert(
        [
            ["on", "moka_pot_1", "flat_stove_1_cook_region"],
            ["on", "moka_pot_2", "flat_stove_1_cook_region"],
            ["turnon", "flat_stove_1"],
        ]
    )
    assert isinstance(both, InSequence) and [type(step) for step in both.steps] == [PickAndPlace, PickAndPlace, TurnOn]
    first, second = both.steps[0], both.steps[1]
    assert first.offset[0] == pytest.approx(SHARED_SURFACE_SPACING / 2) == pytest.approx(0.045)
    assert second.offset[0] == pytest.approx(-0.045) and first.over_others and second.over_others
    alone = make_libero_expert([["on", "moka_pot_1", "flat_stove_1_cook_region"]])
    assert isinstance(alone, PickAndPlace) and not alone.over_others and np.all(alone.offset == 0.0)
    basket = make_libero_expert(
        [["in", "alphabet_soup_1", "basket_1_contain_region"], ["in", "tomato_sauce_1", "basket_1_contain_region"]]
    )
    assert all(np.all(step.offset == 0.0) for step in basket.steps)  # into an object, not onto a surface


def test_what_goes_into_a_drawer_goes_in_before_it_is_shut_and_only_a_top_drawer_is_opened_for_it():
    """LIBERO-10 task 3 lists "close the bottom drawer" first: the bowl goes in before. LIBERO-Goal task 3 puts the
    bowl into a top drawer that starts shut: the bowl dragged clear, the drawer opened from above, the bowl put in;
    into a middle drawer that starts shut (its handle under the top drawer's), refused."""
    from snapflow.envs.libero_expert import CloseDrawer, NoExpertError
    from snapflow.envs.libero_expert.goals import _in_order

    goal = [["close", "white_cabinet_1_bottom_region"], ["in", "akita_black_bowl_1", "white_cabinet_1_bottom_region"]]
    assert _in_order(goal) == [tuple(goal[1]), tuple(goal[0])]
    steps = make_libero_expert(goal).steps
    assert isinstance(steps[1], CloseDrawer) and steps[0].drawer == "white_cabinet_1_bottom"
    into_top = ["in", "akita_black_bowl_1", "wooden_cabinet_1_top_region"]
    for goal in ([into_top], [["open", "wooden_cabinet_1_top_region"], into_top]):
        clear, opening, put = make_libero_expert(goal).steps
        assert isinstance(clear, ClearDrawer) and isinstance(opening, OpenTopDrawer) and isinstance(put, PickAndPlace)
        assert put.drawer == "wooden_cabinet_1_top" and put.rim_out and put.onto_site
    with pytest.raises(NoExpertError, match="wooden_cabinet_1_middle_region"):
        make_libero_expert([["in", "akita_black_bowl_1", "wooden_cabinet_1_middle_region"]])


def test_a_bowl_is_dragged_clear_of_a_drawer_and_gripped_on_the_side_facing_out_of_it():
    """A cabinet at the origin whose top drawer slides out along +y (its handle at +y), a bowl 12 cm to its -x side and
    25 cm out: the bowl is dragged halfway between -x and +y. Put into the opened drawer (8 cm out along +y), it is
    gripped on its rim's +y side turned by RIM_OUT_TURN, the hand turned by as much from upright."""
    state = {
        "robot0_eef_quat": np.array([1.0, 0.0, 0.0, 0.0]),
        "robot0_eef_pos": np.array([-0.2, 0.0, 0.3]),
        "wooden_cabinet_1_pos": np.zeros(3),
        "wooden_cabinet_1_top_handle_pos": np.array([0.0, 0.1, 0.18]),
        "akita_black_bowl_1_pos": np.array([-0.12, 0.25, 0.0]),
    }
    clear = ClearDrawer("akita_black_bowl_1", "wooden_cabinet_1", "top")
    clear.reset(Observation(np.zeros(8), "task", None, {}, state))
    assert clear.direction == pytest.approx(np.array([-1.0, 1.0]) / np.sqrt(2))
    state |= {"wooden_cabinet_1_top_drawer_out": np.array([0.0, 0.08, 0.0])}
    state |= {f"akita_black_bowl_1_{part}": np.zeros(1) for part in ("bottom", "top_offset")}
    state |= {"wooden_cabinet_1_top_region_pos": np.array([0.0, 0.0, 0.18])}
    put = PickAndPlace(
        "akita_black_bowl_1", "wooden_cabinet_1_top_region", True, drawer="wooden_cabinet_1_top", rim_out=True
    )
    put.reset(Observation(np.zeros(8), "task", None, {}, state))
    assert put.side == pytest.approx(np.pi / 2 + RIM_OUT_TURN) and put.placing_turn == pytest.approx(RIM_OUT_TURN)
    rim = put._grasp_point(state)[:2] - state["akita_black_bowl_1_pos"][:2]
    assert np.arctan2(rim[1], rim[0]) == pytest.approx(np.pi / 2 + RIM_OUT_TURN)


def test_a_mug_goes_into_the_microwave_gripped_on_the_side_away_from_its_door_and_the_door_is_pushed_shut():
    """LIBERO-10 task 9: the mug into the microwave, then its door shut. The microwave at (0, 0.35) faces -y (its
    mouth's way out): the mug is gripped on its rim's +x side (towards the control panel, away from the door), the hand
    turned a quarter turn, and let go 7.5 cm out of the origin and 7.5 cm towards the door's side; another goal of the
    microwave is refused."""
    from snapflow.envs.libero_expert import NoExpertError
    from snapflow.envs.libero_expert.microwave import MOUTH_ACROSS, MOUTH_OUT, CloseMicrowave, IntoMicrowave

    goal = [["in", "white_yellow_mug_1", "microwave_1_heating_region"], ["close", "microwave_1"]]
    into, close = make_libero_expert(goal).steps
    assert isinstance(into, IntoMicrowave) and isinstance(close, CloseMicrowave) and close.microwave == "microwave_1"
    state = {
        "robot0_eef_quat": np.array([1.0, 0.0, 0.0, 0.0]),
        "microwave_1_pos": np.array([0.0, 0.35, 0.9]),
        "microwave_1_out": np.array([0.0, -1.0, 0.0]),
    }
    into.reset(Observation(np.zeros(8), "task", None, {}, state))
    assert into.side == pytest.approx(0.0) and MOUTH_OUT == MOUTH_ACROSS * -1 == pytest.approx(0.075)
    assert into.target == pytest.approx(np.array([-0.075, 0.275, 0.9]))
    with pytest.raises(NoExpertError, match="microwave_1"):
        make_libero_expert([["open", "microwave_1"]])


class Hold(Primitive):
    """A primitive that holds the gripper at a fixed command for ``steps`` steps of work, then its last phase."""

    PHASES = ("work", "retreat")
    PHASE_STEPS: ClassVar[dict[str, int]] = {}

    def __init__(self, gripper: float, steps: int) -> None:
        self.gripper, self.steps, self.resets = gripper, steps, []

    def reset(self, observation: Observation, upright: np.ndarray | None = None) -> None:
        super().reset(observation, upright)
        self.resets.append(self.upright.copy())

    def act(self, observation: Observation) -> np.ndarray:
        self.timer += 1
        self.advance(self.phase == "work" and self.timer >= self.steps)
        return np.array([0, 0, 0, 0, 0, 0, self.gripper], dtype=np.float32)


def _observation(quaternion: np.ndarray) -> Observation:
    return Observation(np.zeros(8), "task", None, {}, {"robot0_eef_quat": quaternion})


def test_a_sequence_hands_over_once_a_primitive_has_risen_clear_and_turns_from_the_first_orientation():
    """The first primitive works 3 steps, then spends SETTLED_STEPS in its last phase; the second takes over on the
    step after, planned from that step's observation but turning from the hand's orientation at the episode's start,
    and keeps acting to the end (the last never hands over)."""
    first, second = Hold(-1.0, 3), Hold(1.0, 2)
    sequence = InSequence([first, second])
    start, later = np.array([0.0, 1.0, 0.0, 0.0]), np.array([0.0, 0.0, 1.0, 0.0])
    sequence.reset(_observation(start))
    grippers = [sequence.act(_observation(later))[-1] for _ in range(3 + SETTLED_STEPS + 10)]
    assert grippers == [-1.0] * (3 + SETTLED_STEPS) + [1.0] * 10
    assert len(second.resets) == 1 and np.array_equal(second.resets[0], start)
    with pytest.raises(ValueError, match="at least one"):
        InSequence([])


@pytest.mark.slow
def test_the_scene_gives_each_mugs_rim_and_each_objects_extent():
    """LIBERO-10's two mugs and plates: a mug's rim (the ring of its wall boxes) is centred within 2 cm of its origin,
    4.3 cm in radius, its top 10 cm above the table, and its handle stands out along y; a plate's extent is 2 cm."""
    from snapflow.envs.libero import LiberoEnv

    env = LiberoEnv("libero_10_4", "eval")
    try:
        state = env.reset(0, render=False).privileged
    finally:
        env.close()
    for mug in ("porcelain_mug_1", "white_yellow_mug_1"):
        centre_x, centre_y, radius, top, handle_x, handle_y = state[f"{mug}_rim"]
        assert np.linalg.norm([centre_x, centre_y] - state[f"{mug}_pos"][:2]) < 0.02
        assert (
            radius == pytest.approx(0.043, abs=0.003)
            and abs(handle_y) > 0.99
            and np.hypot(handle_x, handle_y) == pytest.approx(1.0)
        )
        assert top - state[f"{mug}_bottom"][0] == pytest.approx(0.10, abs=0.01)
    assert state["plate_1_top"][0] - state["plate_1_bottom"][0] == pytest.approx(0.02, abs=0.005)
