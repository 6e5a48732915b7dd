"""The Meta-World wrapper and the demonstration format, against the real simulator."""

from __future__ import annotations

import numpy as np
import pytest

from snapflow.data import Demonstrations, DemonstrationError
from snapflow.data.collect import collect_demonstrations
from snapflow.envs.metaworld import MAX_EPISODE_STEPS, MT10_TASKS, STATE_DIM, MetaWorldEnv, make_expert


def test_expert_episode_succeeds_and_episode_stops_at_success():
    env, expert = MetaWorldEnv("drawer-close-v3", "train"), make_expert("drawer-close-v3")
    observation = env.reset(0)
    assert observation.state.shape == (STATE_DIM,) and observation.instruction == "push the drawer closed"
    done = success = False
    while not done:
        observation, success, done = env.step(expert.get_action(observation.state))
    assert success and env.steps < MAX_EPISODE_STEPS


def test_evaluation_variations_differ_from_training_ones():
    train, evaluation = MetaWorldEnv("reach-v3", "train"), MetaWorldEnv("reach-v3", "eval")
    train_starts = np.stack([train.reset(v).state for v in range(10)])
    eval_starts = np.stack([evaluation.reset(v).state for v in range(10)])
    # no evaluation start (object and goal positions) coincides with a training one
    distances = np.abs(train_starts[:, None] - eval_starts[None]).max(-1)
    assert distances.min() > 1e-3


def test_unknown_task_and_variation_are_named():
    with pytest.raises(ValueError, match="unknown Meta-World task"):
        MetaWorldEnv("fly-to-the-moon-v3")
    with pytest.raises(ValueError, match="variation must be in"):
        MetaWorldEnv("reach-v3").reset(10_000)


def test_stored_demonstration_replays_to_success(tmp_path):
    collected = collect_demonstrations(["button-press-topdown-v3"], 2, progress=False)
    collected.save(tmp_path)
    loaded = Demonstrations.load(tmp_path)
    assert np.array_equal(loaded.states, collected.states) and np.array_equal(loaded.actions, collected.actions)
    for number, episode in enumerate(loaded.episodes):
        env = MetaWorldEnv(episode.task, "train")
        observation = env.reset(episode.variation)
        rows = loaded.rows([number])
        success = False
        for row in rows:
            assert np.allclose(observation.state, loaded.states[row], atol=1e-5)
            observation, success, _ = env.step(loaded.actions[row])
        assert success, f"episode {number} did not replay to success"
    assert loaded.instructions == {"button-press-topdown-v3": "press the button from the top"}
    stats = loaded.stats()
    assert len(stats.state_mean) == STATE_DIM and min(stats.state_std) > 0


def _demonstrations(**changes):
    states, actions = np.zeros((5, 3), np.float32), np.zeros((5, 2), np.float32)
    from snapflow.data import Episode

    arguments = dict(states=states, actions=actions, episode_index=np.zeros(5, np.int64),
                     episodes=[Episode("reach-v3", 0, 0, 5)], instructions={"reach-v3": "reach"})
    arguments.update(changes)
    return Demonstrations(**arguments)


@pytest.mark.parametrize(
    "changes, message",
    [
        ({"actions": np.array([[0, 0]] * 4 + [[np.nan, 0]], np.float32)}, "NaN or inf"),
        ({"states": np.zeros((5, 3), np.int64)}, "floating point"),
        ({"episodes": []}, "no episodes"),
        ({"actions": np.zeros((4, 2), np.float32)}, "must be"),
        ({"instructions": {}}, "no instruction"),
    ],
)
def test_bad_demonstrations_are_rejected_with_the_reason(changes, message):
    with pytest.raises(DemonstrationError, match=message):
        _demonstrations(**changes)


def test_loading_a_missing_or_foreign_directory_is_explained(tmp_path):
    with pytest.raises(DemonstrationError, match="snapflow collect"):
        Demonstrations.load(tmp_path)
    (tmp_path / "meta.json").write_text('{"format": "something-else"}')
    (tmp_path / "demonstrations.npz").write_bytes(b"not a zip")
    with pytest.raises(DemonstrationError, match="expected format"):
        Demonstrations.load(tmp_path)


def test_all_mt10_tasks_have_experts():
    for task in MT10_TASKS:
        assert hasattr(make_expert(task), "get_action")
