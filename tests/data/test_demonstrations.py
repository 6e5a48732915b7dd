"""The demonstration format on disk, and collection from a benchmark's experts replayed in the real simulator."""

from __future__ import annotations

import zlib

import numpy as np
import pytest

from snapflow.data import DemonstrationError, Demonstrations, Episode
from snapflow.data.collect import collect_demonstrations, noise_generator
from snapflow.envs.metaworld import STATE_DIM, MetaWorld


@pytest.mark.slow
def test_stored_demonstration_replays_to_success(tmp_path):
    """Simulator test: collected episodes saved and loaded replay step by step to success in a fresh environment."""
    benchmark = MetaWorld()
    collected = collect_demonstrations(benchmark, ["button-press-topdown-v3"], 2, progress=False)
    collected.save(tmp_path)
    loaded = Demonstrations.load(tmp_path)
    assert np.array_equal(loaded.states, collected.states) and np.array_equal(loaded.actions, collected.actions)
    assert loaded.env == collected.env == "metaworld"
    for number, episode in enumerate(loaded.episodes):
        env = benchmark.make_env(episode.task, "train")
        observation = env.reset(episode.variation, render=False)
        success = False
        for row in loaded.rows([number]):
            assert np.allclose(observation.state, loaded.states[row], atol=1e-5)
            observation, success, _ = env.step(loaded.actions[row])
        assert success, f"episode {number} did not replay to success"
    assert loaded.instructions == {"button-press-topdown-v3": "press the button from the top"}
    stats = loaded.stats()
    assert len(stats.state_mean) == STATE_DIM and min(stats.state_std) > 0


@pytest.mark.slow
def test_a_noisy_collection_executes_the_experts_action_plus_its_noise_and_records_the_experts_own():
    """DART: replayed with the noise of its (task, variation), each recorded step is the state the simulator reached
    and the expert's action there; the noise took the arm off the noise-free path, and the expert still succeeded."""
    benchmark, task = MetaWorld(), "reach-v3"
    noisy = collect_demonstrations(benchmark, [task], 1, progress=False, action_noise=0.3)
    clean = collect_demonstrations(benchmark, [task], 1, progress=False)
    episode = noisy.episodes[0]
    env, expert = benchmark.make_env(task, "train"), benchmark.make_expert(task)
    observation, noise = env.reset(episode.variation, render=False), noise_generator(task, episode.variation)
    expert.reset(observation)
    success = False
    for row in noisy.rows([0]):
        assert np.allclose(observation.state, noisy.states[row], atol=1e-5)
        assert np.allclose(expert.act(observation), noisy.actions[row], atol=1e-6)
        observation, success, _ = env.step(noisy.actions[row] + noise.normal(0.0, 0.3, noisy.actions[row].shape))
    assert success and noisy.action_noise == 0.3 and clean.action_noise == 0.0
    steps = min(len(noisy.states), len(clean.states))
    assert np.abs(noisy.states[1:steps, :3] - clean.states[1:steps, :3]).max() > 1e-3, "the noise moved the hand"


@pytest.mark.slow
def test_a_second_set_of_demonstrations_starts_on_other_resets_or_draws_other_noise_and_says_so(tmp_path):
    """--first-variation: the expert starts on later training variations; --noise-seed: other noise on the same
    resets (seed 0 is the noise of every collection before it could be chosen); both saved with the set."""
    benchmark, task = MetaWorld(), "reach-v3"
    first = collect_demonstrations(benchmark, [task], 1, progress=False, action_noise=0.3)
    later = collect_demonstrations(benchmark, [task], 1, progress=False, action_noise=0.3, first_variation=7)
    reseeded = collect_demonstrations(benchmark, [task], 1, progress=False, action_noise=0.3, noise_seed=5)
    assert later.episodes[0].variation >= 7 > first.episodes[0].variation == reseeded.episodes[0].variation
    steps = min(len(first.states), len(reseeded.states))
    assert np.abs(first.states[1:steps] - reseeded.states[1:steps]).max() > 1e-4, "another seed, another path"
    again = noise_generator(task, 0).normal(size=3)
    assert np.array_equal(again, np.random.default_rng([zlib.crc32(task.encode()), 0]).normal(size=3))
    assert not np.array_equal(again, noise_generator(task, 0, seed=5).normal(size=3))
    loaded = Demonstrations.load(later.save(tmp_path / "later"))
    assert (loaded.first_variation, loaded.noise_seed) == (7, 0)
    assert Demonstrations.load(reseeded.save(tmp_path / "reseeded")).noise_seed == 5
    with pytest.raises(ValueError, match=r"must be in \[1, 3\] .* training variations from variation 47\)"):
        collect_demonstrations(benchmark, [task], 4, progress=False, first_variation=47)


@pytest.mark.parametrize("noise", [-0.1, float("nan")])
def test_negative_or_undefined_collection_noise_is_refused_before_the_output_folder_exists(tmp_path, noise):
    from snapflow.data.collect import collect

    with pytest.raises(ValueError, match="action_noise must be a number of at least 0, got (-0.1|nan)"):
        collect(MetaWorld(), ["reach-v3"], 1, tmp_path / "data", progress=False, action_noise=noise)
    assert not (tmp_path / "data").exists()


def _demonstrations(**changes) -> Demonstrations:
    states, actions = np.zeros((5, 3), np.float32), np.zeros((5, 2), np.float32)
    arguments = dict(
        states=states,
        actions=actions,
        episode_index=np.zeros(5, np.int64),
        episodes=[Episode("reach-v3", 0, 0, 5)],
        instructions={"reach-v3": "reach"},
    )
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
    """What would silently corrupt training is refused with the reason."""
    with pytest.raises(DemonstrationError, match=message):
        _demonstrations(**changes)


def test_selected_episodes_come_alone_in_the_order_given_with_their_frames():
    """Three episodes of lengths 2, 1, 2 (steps numbered 0-4): episodes 2 then 0 are steps 3, 4, 0, 1."""
    steps = np.arange(5, dtype=np.float32)[:, None]
    whole = _demonstrations(
        states=np.repeat(steps, 3, axis=1),
        actions=np.repeat(steps, 2, axis=1),
        episode_index=np.array([0, 0, 1, 2, 2]),
        episodes=[Episode("reach-v3", 0, 0, 2), Episode("reach-v3", 1, 2, 1), Episode("reach-v3", 2, 3, 2)],
        images=np.arange(5, dtype=np.uint8).reshape(5, 1, 1, 1).repeat(3, axis=3),
        extra_images={"wrist": np.arange(5, 10, dtype=np.uint8).reshape(5, 1, 1, 1).repeat(3, axis=3)},
    )
    chosen = whole.select([2, 0])
    assert chosen.states[:, 0].tolist() == [3, 4, 0, 1] and chosen.images[:, 0, 0, 0].tolist() == [3, 4, 0, 1]
    assert chosen.extra_images["wrist"][:, 0, 0, 0].tolist() == [8, 9, 5, 6]
    assert chosen.episodes == [Episode("reach-v3", 2, 0, 2), Episode("reach-v3", 0, 2, 2)]
    assert chosen.episode_index.tolist() == [0, 0, 1, 1]


def test_the_benchmark_name_travels_with_the_demonstrations(tmp_path):
    """The env field is saved and loaded; an env that is not a name is refused."""
    demonstrations = _demonstrations(env="metaworld-via-points")
    loaded = Demonstrations.load(demonstrations.save(tmp_path))
    assert loaded.env == "metaworld-via-points" and np.array_equal(loaded.states, demonstrations.states)
    meta = (tmp_path / "meta.json").read_text()
    (tmp_path / "meta.json").write_text(meta.replace('"env": "metaworld-via-points"', '"env": 3'))
    with pytest.raises(DemonstrationError, match="'env' must name a benchmark, got 3"):
        Demonstrations.load(tmp_path)


def test_the_collection_noise_travels_with_the_demonstrations_and_parts_of_different_noise_are_not_joined(tmp_path):
    """Saved and loaded with its noise; a set saved before the field existed loads as noise-free; a bad value and
    parts collected with different noise are refused."""
    noisy = _demonstrations(action_noise=0.1)
    assert Demonstrations.load(noisy.save(tmp_path / "noisy")).action_noise == 0.1
    meta = tmp_path / "noisy" / "meta.json"
    meta.write_text(meta.read_text().replace('"action_noise": 0.1', '"action_noise": -1'))
    with pytest.raises(DemonstrationError, match="meta.json: action_noise must be a number of at least 0, got -1"):
        Demonstrations.load(tmp_path / "noisy")
    older = _demonstrations().save(tmp_path / "older") / "meta.json"
    older.write_text(older.read_text().replace('"action_noise": 0.0,', ""))
    assert "action_noise" not in older.read_text() and Demonstrations.load(tmp_path / "older").action_noise == 0.0
    assert Demonstrations.concatenate([noisy, _demonstrations(action_noise=0.1)]).action_noise == 0.1
    with pytest.raises(DemonstrationError, match=r"collected differently .*: \(0.1, 0, 0\) and \(0.0, 0, 0\)"):
        Demonstrations.concatenate([noisy, _demonstrations()])


def test_loading_a_missing_or_foreign_directory_is_explained(tmp_path):
    """A missing set points at `snapflow collect`; a foreign one names the format expected."""
    with pytest.raises(DemonstrationError, match="snapflow collect"):
        Demonstrations.load(tmp_path)
    (tmp_path / "meta.json").write_text('{"format": "something-else"}')
    (tmp_path / "demonstrations.npz").write_bytes(b"not a zip")
    with pytest.raises(DemonstrationError, match="expected format"):
        Demonstrations.load(tmp_path)


def test_collecting_into_a_folder_another_process_holds_is_refused_before_any_episode(tmp_path):
    from snapflow.data.collect import collect
    from snapflow.reporting.locks import RunLockedError
    from tests.locking import held_by_another_process

    output = tmp_path / "data"
    with held_by_another_process(output, "snapflow collect") as holder:
        with pytest.raises(RunLockedError, match=rf"\(pid {holder.pid}, snapflow collect\)"):
            collect(MetaWorld(), ["reach-v3"], 1, output, progress=False)
    assert [path.name for path in output.iterdir()] == [".snapflow.lock"], "nothing collected, nothing written"


@pytest.mark.slow
def test_an_interrupted_collection_goes_on_from_the_tasks_it_saved_and_equals_an_uninterrupted_one(tmp_path):
    """Each task's demonstrations are kept as the task ends; the same call collects only the others, and the set it
    puts together equals one collected without a stop (seeded resets and noise). A part of another collection is
    refused."""
    from snapflow.data.collect import PARTS, collect

    benchmark, tasks = MetaWorld(), ["reach-v3", "button-press-topdown-v3"]
    whole = collect(benchmark, tasks, 1, tmp_path / "whole", progress=False, action_noise=0.1)
    assert not (tmp_path / "whole" / PARTS).exists(), "the parts go once they are put together"
    # a stop after the first task: its part is saved, the second is not
    first = collect_demonstrations(benchmark, tasks[:1], 1, progress=False, action_noise=0.1)
    first.save(tmp_path / "resumed" / PARTS / tasks[0])
    calls = []
    original = MetaWorld.make_expert
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(MetaWorld, "make_expert", lambda self, task: calls.append(task) or original(self, task))
        resumed = collect(benchmark, tasks, 1, tmp_path / "resumed", progress=False, action_noise=0.1)
    assert calls == [tasks[1]], "only the task not saved is collected"
    assert resumed.episodes == whole.episodes and np.array_equal(resumed.states, whole.states)
    assert np.array_equal(resumed.actions, whole.actions)
    other = collect_demonstrations(benchmark, tasks[:1], 1, progress=False)  # no noise: another collection
    other.save(tmp_path / "mixed" / PARTS / tasks[0])
    with pytest.raises(ValueError, match=r"\.parts/reach-v3 holds a task of another collection"):
        collect(benchmark, tasks, 1, tmp_path / "mixed", progress=False, action_noise=0.1)
