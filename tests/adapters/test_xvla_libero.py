"""An X-VLA of LIBERO's own 7-D actions in LeRobot's LIBERO environment. LeRobot hands every X-VLA the pipeline of
its pretrained LIBERO checkpoint (images ImageNet-normalised, which the policy's own pre-processor does again, then
10-D actions with a 6-D rotation read as axis-angle), so LeRobot 0.6.1's ``lerobot-eval`` stops at the first frame
of such a policy (LeRobot issue #2955); snapflow's adapter gives it the environment's own processors instead."""

from __future__ import annotations

import json
import sys

import pytest

from tests.helpers import run_in_policy_folder
from tests.lerobot_tiny import PI_SKIP

pytestmark = PI_SKIP
IMAGE_SIZE, MAX_STEPS = 32, 6


def pipeline_steps(processors) -> list[str]:
    return [type(step).__name__ for processor in processors for step in processor.steps]


def test_an_x_vla_of_the_datasets_own_actions_takes_the_environments_processors():
    from lerobot.configs.types import FeatureType, PolicyFeature
    from lerobot.envs.configs import LiberoEnv
    from lerobot.envs.factory import make_env_pre_post_processors
    from lerobot.policies.xvla.configuration_xvla import XVLAConfig

    from snapflow.adapters.lerobot.registry import lerobot_env_processors

    def config(width: int) -> XVLAConfig:
        return XVLAConfig(output_features={"action": PolicyFeature(type=FeatureType.ACTION, shape=(width,))})

    env = LiberoEnv(task="libero_spatial")
    xvla_libero = pipeline_steps(make_env_pre_post_processors(env, config(10)))
    assert {"XVLAImageNetNormalizeProcessorStep", "XVLARotation6DToAxisAngleProcessorStep"} <= set(xvla_libero)
    assert pipeline_steps(lerobot_env_processors(env, config(10))) == xvla_libero  # its own checkpoint's layout
    assert pipeline_steps(lerobot_env_processors(env, config(7))) == pipeline_steps(env.get_env_processors())


@pytest.mark.slow
def test_lerobot_eval_runs_an_x_vla_student_of_liberos_7d_actions(vlm_directory, tmp_path):
    """snapflow's ``lerobot-eval`` (``python -m snapflow.adapters.lerobot.libero``, a sweep's ``evaluator =
    "lerobot-eval"``) runs the student's one step in LeRobot's own LIBERO environment, one episode cut short."""
    pytest.importorskip("libero")
    from tests.lerobot_tiny_xvla import save_tiny_xvla_student

    student = save_tiny_xvla_student(
        vlm_directory,
        tmp_path / "student",
        state_dim=8,
        image_key="observation.images.image",
        image_size=IMAGE_SIZE,
        action_dim=7,
    )
    arguments = ["--policy.path=.", "--policy.device=cpu", "--env.type=libero", "--env.task=libero_spatial"]
    arguments += ["--env.task_ids=[0]", f"--env.episode_length={MAX_STEPS}"]
    arguments += [f"--env.observation_height={IMAGE_SIZE}", f"--env.observation_width={IMAGE_SIZE}"]
    arguments += ["--eval.n_episodes=1", "--eval.batch_size=1", f"--output_dir={tmp_path / 'eval'}"]
    run_in_policy_folder(student, [sys.executable, "-m", "snapflow.adapters.lerobot.libero", *arguments])
    info = json.loads((tmp_path / "eval" / "eval_info.json").read_text())
    assert info["overall"]["n_episodes"] == 1 and 0 <= info["overall"]["pc_success"] <= 100
