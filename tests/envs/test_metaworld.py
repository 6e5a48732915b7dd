"""Meta-World 3 (MT10, MT50) behind the Benchmark interface, against the real simulator.

Building MT10 (its task variations) takes tens of seconds, so everything that needs the simulator is marked slow; the
interface's names, instructions and errors are checked without it.
"""

from __future__ import annotations

import numpy as np
import pytest

from snapflow.envs.base import Benchmark, Environment
from snapflow.envs.metaworld import (
    ACTION_DIM,
    INSTRUCTIONS,
    MAX_EPISODE_STEPS,
    MT10_INSTRUCTIONS,
    MT10_TASKS,
    MT50_TASKS,
    STATE_DIM,
    MetaWorld,
    MetaWorldEnv,
    ScriptedExpert,
    _suite,
)
from snapflow.envs.via_points import ViaPointExpert


def test_metaworld_implements_the_benchmark_interface():
    """All 50 tasks of Meta-World 3, each with its own instruction, in two named sets (MT10 the default), and the
    dimensions and step limit of Meta-World 3."""
    import metaworld.policies

    for benchmark, name in ((MetaWorld(), "metaworld"), (MetaWorld(via_points=True), "metaworld-via-points")):
        assert isinstance(benchmark, Benchmark) and benchmark.name == name
        assert benchmark.title.startswith("Meta-World")
        assert (benchmark.state_dim, benchmark.action_dim, benchmark.max_episode_steps) == (39, 4, 500)
        assert benchmark.tasks == MT50_TASKS and set(MT50_TASKS) == set(metaworld.policies.ENV_POLICY_MAP)
        assert benchmark.task_sets == {"mt10": MT10_TASKS, "mt50": MT50_TASKS}
        assert benchmark.default_tasks == MT10_TASKS and set(MT10_TASKS) < set(MT50_TASKS)
        assert [benchmark.instruction(task) for task in MT50_TASKS] == list(INSTRUCTIONS.values())
    assert len(set(INSTRUCTIONS.values())) == 50, "the MLP's one-hot tells the tasks apart by instruction"
    assert MT10_INSTRUCTIONS == {task: INSTRUCTIONS[task] for task in MT10_TASKS}
    assert MetaWorld().instruction("drawer-close-v3") == "push the drawer closed"
    assert MetaWorld().check_tasks(("reach-v3", "push-v3")) == ["reach-v3", "push-v3"]


def test_tasks_are_named_by_set_or_one_by_one():
    benchmark = MetaWorld()
    assert benchmark.resolve_tasks("mt10") == list(MT10_TASKS) and benchmark.resolve_tasks("mt50") == list(MT50_TASKS)
    assert benchmark.resolve_tasks(" assembly-v3, reach-v3 ,") == ["assembly-v3", "reach-v3"]
    assert benchmark.resolve_tasks(["soccer-v3"]) == ["soccer-v3"]
    with pytest.raises(ValueError, match=r"unknown metaworld task\(s\) \['all'\]; give a set \(mt10, mt50\)"):
        benchmark.resolve_tasks("all")
    with pytest.raises(ValueError, match="no task given"):
        benchmark.resolve_tasks(" , ")


def test_unknown_task_empty_task_list_and_unknown_split_are_named():
    """Every entry point names the unknown task and lists the benchmark's, before the simulator is built; a camera it
    lacks is named too."""
    benchmark = MetaWorld()
    message = (
        r"unknown metaworld task\(s\) \['fly-to-the-moon-v3'\]; give a set \(mt10, mt50\) or tasks of \['assembly-v3'"
    )
    for call in (
        lambda: benchmark.check_tasks(["reach-v3", "fly-to-the-moon-v3"]),
        lambda: benchmark.instruction("fly-to-the-moon-v3"),
        lambda: benchmark.make_expert("fly-to-the-moon-v3"),
        lambda: benchmark.make_env("fly-to-the-moon-v3", "train"),
        lambda: MetaWorldEnv("fly-to-the-moon-v3"),
    ):
        with pytest.raises(ValueError, match=message):
            call()
    with pytest.raises(ValueError, match=r"unknown metaworld-via-points task\(s\) \['fly'\]"):
        MetaWorld(via_points=True).check_tasks(["fly"])
    with pytest.raises(ValueError, match="no task given"):
        benchmark.check_tasks([])
    for call in (lambda: benchmark.num_variations("test"), lambda: MetaWorldEnv("reach-v3", "test")):
        with pytest.raises(ValueError, match=r"split must be one of \['train', 'eval'\], got 'test'"):
            call()
    with pytest.raises(ValueError, match=r"metaworld has no camera\(s\) \['image2'\]: besides its main camera"):
        benchmark.make_env("reach-v3", "eval", 64, extra_cameras=["image2"])


def test_experts_are_meta_worlds_scripted_policies_routed_through_a_via_point_in_the_variant():
    """make_expert gives the task's own scripted policy; the via-point variant wraps it in a ViaPointExpert."""
    for task in MT50_TASKS:  # Meta-World names a task's policy after it: hand-insert-v3 -> SawyerHandInsertV3Policy
        words = task.removesuffix("-v3").replace("peg-insert", "peg-insertion").split("-")
        expected = "Sawyer" + "".join(word.capitalize() for word in words) + "V3Policy"
        assert type(MetaWorld().make_expert(task).policy).__name__ == expected, task
    plain = MetaWorld().make_expert("peg-insert-side-v3")
    assert isinstance(plain, ScriptedExpert) and type(plain.policy).__name__ == "SawyerPegInsertionSideV3Policy"
    routed = MetaWorld(via_points=True).make_expert("peg-insert-side-v3")
    assert isinstance(routed, ViaPointExpert) and isinstance(routed.expert, ScriptedExpert)
    assert type(routed.expert.policy).__name__ == "SawyerPegInsertionSideV3Policy"


@pytest.mark.slow
@pytest.mark.parametrize("via", [False, True], ids=["metaworld", "via-points"])
@pytest.mark.parametrize("task", MT10_TASKS)
def test_every_mt10_expert_succeeds_on_a_training_variation(task: str, via: bool):
    """Simulator test: each task's expert, as make_expert builds it, succeeds on the first training variation and the
    episode stops at that success, well before the step limit; observations are the 39-d state and the instruction."""
    benchmark = MetaWorld(via_points=via)
    env, expert = benchmark.make_env(task, "train"), benchmark.make_expert(task)
    assert isinstance(env, Environment) and env.task == task and env.instruction == benchmark.instruction(task)
    observation = env.reset(0, render=False)
    assert observation.state.shape == (STATE_DIM,) and observation.state.dtype == np.float32
    assert observation.instruction == MT10_INSTRUCTIONS[task] and observation.image is None
    expert.reset(observation)
    done = success = False
    while not done:
        action = expert.act(observation)
        assert action.shape == (ACTION_DIM,)
        observation, success, done = env.step(action)
    assert success and env.steps < MAX_EPISODE_STEPS
    env.close()


@pytest.mark.slow
def test_variations_per_split_and_evaluation_variations_differ_from_training_ones():
    """Simulator test: 50 variations a task in each split, none of the evaluation starts (object and goal positions)
    equal to a training one; a variation out of range is named."""
    benchmark = MetaWorld()
    assert benchmark.num_variations("train") == benchmark.num_variations("eval") == 50
    train, evaluation = benchmark.make_env("reach-v3", "train"), benchmark.make_env("reach-v3", "eval")
    train_starts = np.stack([train.reset(v, render=False).state for v in range(10)])
    eval_starts = np.stack([evaluation.reset(v, render=False).state for v in range(10)])
    distances = np.abs(train_starts[:, None] - eval_starts[None]).max(-1)
    assert distances.min() > 1e-3
    with pytest.raises(ValueError, match=r"variation must be in \[0, 50\), got 10000"):
        train.reset(10_000)


@pytest.mark.slow
def test_mt10_tasks_keep_mt10s_variations_and_the_other_tasks_take_mt1s():
    """Simulator test: an MT10 task's variations are MT10(seed)'s, as every MT10 result was measured on; another
    task's are MT1(task, seed)'s; both splits have 50 and differ; the MT10 tasks of a split share one MT10."""
    import metaworld

    for split, seed in (("train", 0), ("eval", 1)):
        mt10 = metaworld.MT10(seed=seed)
        env = MetaWorldEnv("push-v3", split)
        assert [t.data for t in env._variations] == [t.data for t in mt10.train_tasks if t.env_name == "push-v3"]
        # every MT10 task of a split reads one MT10, built once a process (each build resets its envs 500 times)
        assert _suite("push-v3", seed) is _suite("reach-v3", seed) is _suite(MT10_TASKS[0], seed)
        env = MetaWorldEnv("shelf-place-v3", split)
        assert [t.data for t in env._variations] == [
            t.data for t in metaworld.MT1("shelf-place-v3", seed=seed).train_tasks
        ]
        assert len(env._variations) == 50
    train, evaluation = MetaWorldEnv("shelf-place-v3", "train"), MetaWorldEnv("shelf-place-v3", "eval")
    assert np.abs(train.reset(0, render=False).state - evaluation.reset(0, render=False).state).max() > 1e-3


@pytest.mark.slow
@pytest.mark.parametrize("task", ["assembly-v3", "hammer-v3", "soccer-v3"])
def test_tasks_beyond_mt10_run_their_expert_to_success(task: str):
    """Simulator test: a task outside MT10 (its own instruction, its own scripted expert) reaches success within the
    step limit on one of its first training variations, with 39-d states."""
    benchmark = MetaWorld()
    env, expert = benchmark.make_env(task, "train"), benchmark.make_expert(task)
    for variation in range(5):
        observation = env.reset(variation, render=False)
        assert observation.state.shape == (STATE_DIM,) and observation.instruction == INSTRUCTIONS[task]
        expert.reset(observation)
        done = success = False
        while not done:
            observation, success, done = env.step(expert.act(observation))
        if success:
            break
    assert success and env.steps < MAX_EPISODE_STEPS
    env.close()


def test_a_report_title_names_the_task_set_it_ran():
    from snapflow.envs.metaworld import MT10_TASKS, MT50_TASKS, MetaWorld

    assert MetaWorld().describe(MT10_TASKS) == "Meta-World MT10"
    assert MetaWorld().describe(MT50_TASKS) == "Meta-World MT50"
    assert MetaWorld().describe(["reach-v3", "push-v3"]) == "Meta-World (2 tasks)"
    assert MetaWorld(via_points=True).describe(MT10_TASKS) == "Meta-World MT10, via-point variant"
