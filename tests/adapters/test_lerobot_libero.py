"""LeRobot on LIBERO end to end (the LIBERO guide's chain, ``BENCH=libero SHORT=1 bash scripts/lerobot-smolvla.sh``):
`snapflow collect --env libero --lerobot-dataset` writes the scripted experts' episodes with LeRobot's own writer,
LeRobot's ``LeRobotDataset`` reads them back, their features are those LeRobot's own LIBERO environment gives a
policy (so ``lerobot-eval --env.type=libero`` runs a policy trained on them unchanged), and a SmolVLA teacher trained
on them and its student are evaluated by snapflow's evaluator and by LeRobot's LIBERO environment."""

from __future__ import annotations

import json
import sys
from importlib.metadata import PackageNotFoundError, distribution
from pathlib import Path

import numpy as np
import pytest

from snapflow.adapters.lerobot_types import lerobot_loads_plugins
from snapflow.data.demonstrations import Demonstrations
from tests.helpers import run_in_policy_folder, run_short_lerobot_chain

pytest.importorskip("lerobot", reason="LeRobot is installed by the README's test command; this environment lacks it")
pytest.importorskip("libero")

IMAGE_SIZE = 32  # the short chain's
MAX_STEPS = 10  # and the steps its episodes are cut at


# ~150 s on two busy cores, paid once for the module's tests: the LIBERO guide's whole LeRobot chain on LIBERO, whose
# environments alone take 4-9 s to make and ~20 ms a step; its parts (collection, dataset, training, both evaluators)
# are each at their smallest (one demonstration, four training steps, one episode a row cut at MAX_STEPS).
@pytest.fixture(scope="module")
def collected(tmp_path_factory):
    """The short chain on one LIBERO-Spatial task: one demonstration with 32-pixel images from both cameras as npz
    and as a LeRobotDataset, a tiny SmolVLA teacher, its student, one episode of each row in snapflow's evaluator and
    one of the student in LeRobot's LIBERO environment, from LIBERO's first initial state."""
    return run_short_lerobot_chain(tmp_path_factory.mktemp("libero"), "libero")


@pytest.mark.slow
def test_lerobot_reads_back_both_cameras_state_and_actions(collected):
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    demonstrations = Demonstrations.load(collected / "data")
    assert demonstrations.env == "libero" and demonstrations.images.shape[1:] == (IMAGE_SIZE, IMAGE_SIZE, 3)
    assert demonstrations.states.shape[1] == 8 and demonstrations.actions.shape[1] == 7
    assert set(demonstrations.extra_images) == {"image2"}
    dataset = LeRobotDataset("local/lerobot", root=collected / "lerobot")
    assert dataset.num_episodes == len(demonstrations.episodes) == 1
    assert dataset.num_frames == len(demonstrations.states)
    assert dataset.fps == 20
    last = len(demonstrations.states) - 1
    for row in (0, last):
        frame = dataset[row]
        np.testing.assert_allclose(frame["observation.state"].numpy(), demonstrations.states[row], atol=1e-6)
        np.testing.assert_allclose(frame["action"].numpy(), demonstrations.actions[row], atol=1e-6)
        for key, frames in (("image", demonstrations.images), ("image2", demonstrations.extra_images["image2"])):
            image = frame[f"observation.images.{key}"]  # LeRobot gives CHW floats in [0, 1]
            np.testing.assert_allclose(image.permute(1, 2, 0).numpy() * 255, frames[row], atol=1)
        assert frame["task"] == demonstrations.instructions["libero_spatial_0"]


@pytest.mark.slow
def test_its_features_are_those_lerobots_libero_environment_gives_a_policy(collected):
    """The dataset's policy features equal LeRobot's LiberoEnv at the same image size after LeRobot's LIBERO
    processor (two cameras, the 8-D state it assembles from the robot's state), and its action is LeRobot's 7-D."""
    from lerobot.configs.types import FeatureType, PolicyFeature
    from lerobot.datasets.lerobot_dataset import LeRobotDatasetMetadata
    from lerobot.envs.configs import LiberoEnv
    from lerobot.envs.utils import env_to_policy_features
    from lerobot.processor.env_processor import LiberoProcessorStep

    from snapflow.adapters.lerobot.dataset import policy_features

    metadata = LeRobotDatasetMetadata("local/lerobot", root=collected / "lerobot")
    ours = policy_features(metadata.features)
    environment = env_to_policy_features(LiberoEnv(observation_height=IMAGE_SIZE, observation_width=IMAGE_SIZE))
    by_type: dict = {}
    for key, feature in environment.items():
        by_type.setdefault(feature.type, {})[key] = feature
    theirs = {
        key: f for group in LiberoProcessorStep().transform_features(by_type).values() for key, f in group.items()
    }
    assert ours == theirs
    assert theirs["observation.state"] == PolicyFeature(type=FeatureType.STATE, shape=(8,))
    assert theirs["observation.images.image2"].shape == (3, IMAGE_SIZE, IMAGE_SIZE)
    assert ours["action"] == PolicyFeature(type=FeatureType.ACTION, shape=(7,))


@pytest.mark.slow
def test_the_student_runs_in_snapflows_evaluator_and_in_lerobots_libero_environment(collected):
    """Both cameras reach the SmolVLA through LeRobot's processors in snapflow's evaluator (teacher, naive and
    student rows on LIBERO's first initial state), and LeRobot's own LIBERO environment, built on this package
    through snapflow's initial-state shim, runs the student's one-step sampling: by LeRobot's ``lerobot-eval`` where
    LeRobot loads snapflow's plugin policies (>= 0.5), else by ``snapflow eval --lerobot-env``."""
    report = json.loads((collected / "eval" / "report.json").read_text())
    rows = report["rows"]
    assert [row["mode"] for row in rows.values()] == ["teacher-10", "naive-1", "snapflow-1"]
    assert report["max_episode_steps"] == MAX_STEPS
    for row in rows.values():
        assert set(row["success"]) == {"libero_spatial_0", "mean"} and row["success"]["mean"]["episodes"] == 1
    folder = collected / "lerobot-eval" / "libero_spatial_0"
    if lerobot_loads_plugins():  # LeRobot's lerobot-eval itself, the student's type loaded from snapflow's plugin
        info = json.loads((folder / "eval_info.json").read_text())
        (task,) = info["per_task"]
        assert (task["task_group"], task["task_id"], len(task["metrics"]["successes"])) == ("libero_spatial", 0, 1)
        assert info["overall"]["n_episodes"] == 1
        return
    lerobot = json.loads((folder / "report.json").read_text())
    assert (lerobot["env"], lerobot["task"], list(lerobot["modes"])) == ("libero", "libero_spatial", ["snapflow-1"])
    assert lerobot["modes"]["snapflow-1"]["nfe"] == 1
    assert lerobot["modes"]["snapflow-1"]["overall"]["n_episodes"] == 1


# ~35 s on two busy cores: one lerobot-eval subprocess (the teacher's ten steps) of one episode cut at MAX_STEPS, the
# least there is (LeRobot's LiberoEnv takes ~20 s to make); the student's is the chain's own, read back.
@pytest.mark.slow
@pytest.mark.skipif(
    not lerobot_loads_plugins(), reason="lerobot-eval loads snapflow's student types from lerobot 0.5 on"
)
def test_lerobot_eval_task_by_task_reads_back_as_an_evaluation_row_with_lerobots_own_files_kept(collected, tmp_path):
    """What a sweep's ``evaluator = "lerobot-eval"`` table runs: LeRobot's ``lerobot-eval`` on the teacher (its
    Euler steps) and on the student (its sampling mode: the chain ran it as the LIBERO guide does), one task at a
    time, read back as snapflow's evaluation row; LeRobot's ``eval_info.json`` kept as it wrote it; a finished task is
    not run again; a teacher has no jump."""
    from snapflow.errors import InvalidInputError
    from snapflow.evaluation.lerobot_eval import EVAL_INFO, run_lerobot_eval
    from snapflow.flow.modes import SNAPFLOW_1, TEACHER_10

    task = "libero_spatial_0"
    runs = (("teacher", TEACHER_10, tmp_path / "teacher-10", 2), ("student", SNAPFLOW_1, collected / "lerobot-eval", 4))
    for policy, mode, output, n_action_steps in runs:
        kept = tmp_path / "kept" / mode.name
        arguments = (collected / policy / "lerobot_policy", [task], 1, IMAGE_SIZE, n_action_steps, mode, output)
        row = run_lerobot_eval(*arguments, threads=1, kept=kept, max_episode_steps=MAX_STEPS)
        info = json.loads((output / task / EVAL_INFO).read_text())
        assert json.loads((kept / task / EVAL_INFO).read_text()) == info
        assert (row.mode, row.nfe, row.success[task].episodes) == (mode.name, mode.num_steps, 1)
        assert row.success["mean"].successes == sum(info["per_task"][0]["metrics"]["successes"])
        log = (output / f"{task}.log").read_text()
        asked = "'sampling_mode': 'snapflow-1'" if mode.jump else "'num_steps': 10"
        assert asked in log and f"'n_action_steps': {n_action_steps}" in log
        assert f"'episode_length': {MAX_STEPS}" in log
        written = (output / f"{task}.log").stat().st_mtime_ns
        assert run_lerobot_eval(*arguments, threads=1) == row
        assert (output / f"{task}.log").stat().st_mtime_ns == written, "a finished task is read back, not run again"
    with pytest.raises(InvalidInputError, match="has no jump to sample snapflow-1"):
        run_lerobot_eval(collected / "teacher" / "lerobot_policy", [task], 1, IMAGE_SIZE, 2, SNAPFLOW_1, tmp_path / "x")


# ~35 s on two busy cores: LeRobot's LiberoEnv takes ~20 s to make, and the episode is cut at MAX_STEPS.
@pytest.mark.slow
@pytest.mark.skipif(
    not lerobot_loads_plugins(), reason="lerobot-eval loads snapflow's student types from lerobot 0.5 on"
)
def test_lerobots_own_lerobot_eval_command_runs_the_student_as_the_readme_types_it(collected, tmp_path):
    """``cd <student folder> && lerobot-eval --policy.path=. --env.type=libero ...``, LeRobot's console script as a
    user runs it (the README's line): LeRobot imports snapflow's plugin distribution by itself and runs the
    ``snapflow_smolvla`` student, whose SmolVLM it finds inside the folder. LeRobot's own initial-state files are not
    those this LIBERO package ships, so the episode starts from a seeded placement instead."""
    try:
        distribution("lerobot_policy_snapflow")
    except PackageNotFoundError:
        pytest.fail(
            "the plugin distribution is not installed: the README's test command installs plugins/lerobot_policy_snapflow"
        )
    student = collected / "student" / "lerobot_policy"
    assert json.loads((student / "config.json").read_text())["type"] == "snapflow_smolvla"
    arguments = ["--policy.path=.", "--policy.device=cpu", "--env.type=libero", "--env.task=libero_spatial"]
    arguments += ["--env.task_ids=[0]", "--env.init_states=false", f"--env.episode_length={MAX_STEPS}"]
    arguments += [f"--env.observation_height={IMAGE_SIZE}", f"--env.observation_width={IMAGE_SIZE}"]
    arguments += ["--eval.n_episodes=1", "--eval.batch_size=1", f"--output_dir={tmp_path / 'eval'}"]
    finished = run_in_policy_folder(student, [str(Path(sys.executable).with_name("lerobot-eval")), *arguments])
    assert "Imported third-party plugin: lerobot_policy_snapflow" in finished.stderr
    info = json.loads((tmp_path / "eval" / "eval_info.json").read_text())
    assert info["overall"]["n_episodes"] == 1 and 0 <= info["overall"]["pc_success"] <= 100
