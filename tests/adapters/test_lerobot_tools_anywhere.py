"""LeRobot's own tools on a SnapFlow student folder as snapflow keeps it (its SmolVLM inside, named relative to the
folder), started in another working directory and given the folder by a relative path: the student's pre-processor
carries its tokenizer in its tokenizer step's state, which tokenizes as LeRobot's own step, and the student type names
the kept VLM to LeRobot by absolute path. A teacher (LeRobot's own type) keeps LeRobot's step."""

from __future__ import annotations

import json
import os
import shutil
import sys
from importlib.metadata import version
from pathlib import Path

import pytest
import torch
from packaging.version import Version

pytest.importorskip("lerobot", reason="LeRobot is installed by the README's test command; this environment lacks it")

from snapflow.adapters.lerobot.local_vlm import BUNDLED_VLM, bundle_vlm  # noqa: E402
from snapflow.adapters.lerobot.xvla import XVLAFlowPolicy  # noqa: E402
from snapflow.adapters.lerobot_types import PLUGIN_LEROBOT, lerobot_loads_plugins  # noqa: E402
from tests.helpers import run_checked, run_tiny_lerobot_train  # noqa: E402
from tests.lerobot_tiny import build_tiny_smolvla, save_tiny_student, tiny_batch, write_tiny_smolvlm  # noqa: E402

PLUGINS = pytest.mark.skipif(
    not lerobot_loads_plugins(), reason=f"LeRobot's tools import third-party policies from lerobot {PLUGIN_LEROBOT} on"
)
XVLA = pytest.mark.skipif(
    Version(version("lerobot")) < Version(XVLAFlowPolicy.minimum_lerobot),
    reason=f"snapflow's X-VLA adapter needs lerobot >= {XVLAFlowPolicy.minimum_lerobot}",
)
PREPROCESSOR = "policy_preprocessor.json"
TASKS = ["pick the red cube", "open the drawer of a zebra", " ".join(["push the green goal"] * 6)]  # UNK, truncated


def _files(folder: Path) -> dict[str, bytes]:
    """Every file under ``folder`` by its path relative to it."""
    return {str(path.relative_to(folder)): path.read_bytes() for path in sorted(folder.rglob("*")) if path.is_file()}


def _steps(folder: Path) -> list[dict]:
    return json.loads((folder / PREPROCESSOR).read_text())["steps"]


def _preprocessor(folder: Path | str):
    """The pre-processor saved in ``folder``, as LeRobot's loader builds it with no override."""
    from lerobot.processor import PolicyProcessorPipeline

    return PolicyProcessorPipeline.from_pretrained(str(folder), config_filename=PREPROCESSOR)


def _preprocessed(preprocessor) -> dict[str, torch.Tensor]:
    batch = {key: value[:3] for key, value in tiny_batch(batch_size=3).items() if "language" not in key}
    return preprocessor({**batch, "task": TASKS})


def _smolvla_student(vlm: Path, folder: Path) -> Path:
    return save_tiny_student(vlm, folder, state_dim=6, image_key="observation.images.top", image_size=64)


def _xvla_student(vlm: Path, folder: Path) -> Path:
    from tests.lerobot_tiny_xvla import save_tiny_xvla_student

    return save_tiny_xvla_student(vlm, folder)


@pytest.mark.parametrize("save", [_smolvla_student, pytest.param(_xvla_student, marks=XVLA)], ids=["smolvla", "xvla"])
def test_a_kept_students_tokenizer_travels_in_its_state_and_tokenizes_as_lerobots_own_step(save, tmp_path, monkeypatch):
    import snapflow.adapters.lerobot.plugin  # noqa: F401 - registers the step (LeRobot >= 0.5's tools import it)

    vlm = write_tiny_smolvlm(tmp_path / "gone" / "smolvlm").resolve()
    folder = save(vlm, tmp_path / "student")
    expected = _preprocessed(_preprocessor(folder))  # LeRobot's own step, the tokenizer named by absolute path
    assert bundle_vlm(folder) and not bundle_vlm(folder)
    shutil.rmtree(tmp_path / "gone")

    (tokenizer,) = [step for step in _steps(folder) if "tokenizer" in step["registry_name"]]
    assert tokenizer["registry_name"] == "snapflow_tokenizer_processor" and "tokenizer_name" not in tokenizer["config"]
    assert (folder / tokenizer["state_file"]).is_file()
    (tmp_path / "elsewhere").mkdir()
    monkeypatch.chdir(tmp_path / "elsewhere")
    carried = _preprocessor(Path("..") / "student")
    actual = _preprocessed(carried)
    assert actual.keys() == expected.keys() and "observation.language.tokens" in actual
    for key, value in expected.items():
        assert torch.equal(actual[key], value) if isinstance(value, torch.Tensor) else actual[key] == value, key

    carried.save_pretrained(tmp_path / "checkpoint")  # as lerobot-train saves it again in each checkpoint
    state = tokenizer["state_file"]
    assert (tmp_path / "checkpoint" / state).read_bytes() == (folder / state).read_bytes()


def _as_kept_before(folder: Path) -> Path:
    """``folder`` as :func:`bundle_vlm` kept a policy before students carried their tokenizer: its VLM copied inside,
    LeRobot's own tokenizer step naming it relative to the folder."""
    config = json.loads((folder / "config.json").read_text())
    shutil.copytree(config["vlm_model_name"], folder / BUNDLED_VLM)
    for name in ("config.json", PREPROCESSOR):
        path = folder / name
        path.write_text(path.read_text().replace(json.dumps(config["vlm_model_name"]), json.dumps(BUNDLED_VLM)))
    return folder


def test_a_student_kept_before_takes_the_step_when_bundled_again_and_a_teacher_keeps_lerobots(vlm_directory, tmp_path):
    """What the committed kept students need (``bundle_vlm`` on each), and what a teacher keeps: LeRobot 0.4.4 reads
    its folder too, and snapflow cannot hook LeRobot's own types."""
    from lerobot.configs.policies import PreTrainedConfig
    from lerobot.policies.factory import make_pre_post_processors

    import snapflow.adapters.lerobot.plugin  # noqa: F401 - registers the student types
    from snapflow.adapters.lerobot.local_vlm import saved_processors

    student = _as_kept_before(_smolvla_student(vlm_directory, tmp_path / "student"))
    config = PreTrainedConfig.from_pretrained(student)
    expected = _preprocessed(saved_processors(config, student, "cpu")[0])
    assert bundle_vlm(student)
    assert [step["registry_name"] for step in _steps(student)].count("snapflow_tokenizer_processor") == 1
    actual = _preprocessed(saved_processors(config, student, "cpu")[0])
    assert torch.equal(actual["observation.language.tokens"], expected["observation.language.tokens"])

    teacher = tmp_path / "teacher"
    policy = build_tiny_smolvla(vlm_directory)
    policy.save_pretrained(teacher)
    for processor in make_pre_post_processors(policy.config, dataset_stats=None):
        processor.save_pretrained(teacher)
    assert bundle_vlm(teacher)
    (tokenizer,) = [step for step in _steps(teacher) if "tokenizer" in step["registry_name"]]
    assert tokenizer == {"registry_name": "tokenizer_processor", "config": tokenizer["config"]}
    assert tokenizer["config"]["tokenizer_name"] == BUNDLED_VLM


# ~25 s on two busy cores: LeRobot's LiberoEnv takes most of it to make; the episode is cut at 6 steps
@pytest.mark.slow
@PLUGINS
def test_lerobot_eval_runs_a_kept_student_from_another_directory(tmp_path):
    pytest.importorskip("libero")
    vlm = write_tiny_smolvlm(tmp_path / "gone" / "smolvlm").resolve()
    # the features LeRobot's LIBERO env gives at 32 pixels: an 8-D state, its agent-view camera, 7-D actions
    student = save_tiny_student(vlm, tmp_path / "student", 8, "observation.images.image", 32, action_dim=7)
    bundle_vlm(student)
    shutil.rmtree(tmp_path / "gone")
    before = _files(student)
    (tmp_path / "elsewhere").mkdir()
    arguments = ["--policy.path=../student", "--policy.device=cpu", "--env.type=libero", "--env.task=libero_spatial"]
    arguments += ["--env.task_ids=[0]", "--env.init_states=false", "--env.episode_length=6"]
    arguments += ["--env.observation_height=32", "--env.observation_width=32", "--eval.n_episodes=1"]
    arguments += ["--eval.batch_size=1", f"--output_dir={tmp_path / 'eval'}"]
    environment = {"MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl"), "HF_HUB_OFFLINE": "1"}
    command = [sys.executable, "-m", "lerobot.scripts.lerobot_eval", *arguments]
    finished = run_checked(command, environment, cwd=tmp_path / "elsewhere", timeout=600)
    assert "Imported third-party plugin: lerobot_policy_snapflow" in finished.stderr
    assert json.loads((tmp_path / "eval" / "eval_info.json").read_text())["overall"]["n_episodes"] == 1
    assert _files(student) == before, "nothing written into the policy folder"


# ~10-15 s on two busy cores: lerobot-train's start, two steps and a checkpoint
@pytest.mark.slow
@PLUGINS
def test_lerobot_train_steps_a_written_student_from_another_directory_and_its_kept_checkpoint_is_relative(tmp_path):
    """``snapflow distill --lerobot-train`` writes the student of a teacher kept with its SmolVLM inside; LeRobot's
    ``lerobot-train`` trains it from elsewhere. Its checkpoint names the student's SmolVLM by absolute path (LeRobot
    saves the config it trained with, which the student type resolved); keeping it names it relatively again."""
    from lerobot.policies.factory import make_pre_post_processors

    from snapflow.sources import open_policy
    from snapflow.training.checkpoint import copy_checkpoint
    from snapflow.training.lerobot_student import write_student
    from tests.lerobot_tiny import write_tiny_dataset

    data = write_tiny_dataset(tmp_path / "data", episodes=2, frames=8)
    teacher, policy = tmp_path / "teacher", build_tiny_smolvla(write_tiny_smolvlm(tmp_path / "gone").resolve())
    policy.save_pretrained(teacher)
    for processor in make_pre_post_processors(policy.config, dataset_stats=None):
        processor.save_pretrained(teacher)
    bundle_vlm(teacher)
    shutil.rmtree(tmp_path / "gone")
    student = write_student(str(teacher), tmp_path / "student")
    assert json.loads((student / "config.json").read_text())["vlm_model_name"] == BUNDLED_VLM
    before = _files(student)
    (tmp_path / "elsewhere").mkdir()
    checkpoint = run_tiny_lerobot_train(
        Path("..") / "student", data, tmp_path / "run", 2, 4, "--log_freq=1", cwd=tmp_path / "elsewhere"
    )
    assert _files(student) == before, "nothing written into the policy folder"

    absolute = str((student / BUNDLED_VLM).resolve())
    assert json.loads((checkpoint / "config.json").read_text())["vlm_model_name"] == absolute
    assert json.loads((checkpoint / "train_config.json").read_text())["policy"]["vlm_model_name"] == absolute
    kept = copy_checkpoint(checkpoint, tmp_path / "kept", prepare=bundle_vlm)  # as a sweep keeps a finished run
    shutil.rmtree(student)
    assert json.loads((kept / "config.json").read_text())["vlm_model_name"] == BUNDLED_VLM
    assert json.loads((kept / "train_config.json").read_text())["policy"]["vlm_model_name"] == BUNDLED_VLM
    assert "snapflow_tokenizer_processor" in [step["registry_name"] for step in _steps(kept)]
    assert open_policy(kept).distilled
