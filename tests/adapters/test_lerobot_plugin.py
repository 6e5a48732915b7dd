"""snapflow's LeRobot plugin: a policy ``snapflow distill`` saved is a LeRobot policy of its own type
(``snapflow_smolvla``), loaded by LeRobot's own loaders and tools, sampling in one step, with its teacher one config
field (``sampling_mode``) away. On LeRobot >= 0.5, ``lerobot-eval`` itself runs it in Meta-World (and, as a user types
it, on LIBERO: tests/adapters/test_lerobot_libero.py) through the ``lerobot_policy_snapflow`` distribution."""

from __future__ import annotations

import json
import os
import sys
from importlib.metadata import version
from pathlib import Path

import pytest
import torch

pytest.importorskip("lerobot", reason="LeRobot is installed by the README's test command; this environment lacks it")

from snapflow.adapters.lerobot import load_distilled, save_distilled, wrap_policy  # noqa: E402
from snapflow.adapters.lerobot_types import PLUGIN_LEROBOT, lerobot_loads_plugins  # noqa: E402
from snapflow.policies.checkpoint import CheckpointError  # noqa: E402
from tests.lerobot_tiny import build_tiny_smolvla, model_inputs, randomise_target_time, tiny_batch  # noqa: E402

PLUGINS = pytest.mark.skipif(
    not lerobot_loads_plugins(),
    reason=f"LeRobot imports third-party policies from lerobot {PLUGIN_LEROBOT} on; lerobot {version('lerobot')} is installed",
)


@pytest.fixture
def student(vlm_directory, tmp_path) -> Path:
    """A distilled tiny SmolVLA (phi_s non-zero) as ``snapflow distill`` exports it."""
    return save_distilled(randomise_target_time(wrap_policy(build_tiny_smolvla(vlm_directory))), tmp_path / "student")


def _sample(policy, batch: dict[str, torch.Tensor], noise: torch.Tensor) -> tuple[torch.Tensor, int]:
    """The policy's own ``model.sample_actions`` on ``batch`` and how many denoising passes it ran."""
    model, calls = policy.model, []
    denoise_step = model.denoise_step
    model.denoise_step = lambda *args, **kwargs: calls.append(1) or denoise_step(*args, **kwargs)
    try:
        with torch.no_grad():
            return model.sample_actions(*model_inputs(policy, batch), noise=noise), len(calls)
    finally:
        del model.denoise_step


def test_lerobots_own_loader_gives_the_one_step_student_and_its_teacher_one_field_away(student):
    from lerobot.configs.policies import PreTrainedConfig

    from snapflow.adapters.lerobot.plugin import student_config_class, student_policy

    SnapFlowSmolVLAConfig, SnapFlowSmolVLAPolicy = student_config_class("smolvla"), student_policy("smolvla")  # noqa: N806

    saved = json.loads((student / "config.json").read_text())
    assert saved["type"] == "snapflow_smolvla" and saved["sampling_mode"] == "snapflow-1"
    batch, noise = tiny_batch(), torch.randn(4, 4, 4, generator=torch.Generator().manual_seed(3))

    policy = SnapFlowSmolVLAPolicy.from_pretrained(student)  # LeRobot's from_pretrained, untouched
    assert isinstance(policy.config, SnapFlowSmolVLAConfig)
    one_step, passes = _sample(policy, batch, noise)
    assert passes == 1
    expected, _ = _sample(load_distilled(student).policy, batch, noise)
    assert torch.equal(one_step, expected), "LeRobot's loader and snapflow's must give the same student"

    # the teacher: the same folder with one config field changed, as lerobot-eval's --policy.sampling_mode does
    config = PreTrainedConfig.from_pretrained(student, cli_overrides=["--sampling_mode=teacher-10"])
    teacher_mode = SnapFlowSmolVLAPolicy.from_pretrained(student, config=config)
    ten_steps, passes = _sample(teacher_mode, batch, noise)
    assert passes == 10
    # ... is LeRobot's own 10-step Euler sampler (the class's, not the instance's) on the same network (s = t)
    teacher_mode.config.num_steps = 10
    with torch.no_grad():
        lerobots = type(teacher_mode.model).sample_actions(
            teacher_mode.model, *model_inputs(teacher_mode, batch), noise=noise
        )
    assert torch.allclose(ten_steps, lerobots, atol=1e-5)
    assert not torch.allclose(one_step, ten_steps, atol=1e-3)


def test_a_student_without_phi_s_or_with_an_unknown_mode_is_refused(student, tmp_path):
    import shutil

    from safetensors.torch import load_file, save_file

    from snapflow.adapters.lerobot.plugin import student_policy

    SnapFlowSmolVLAPolicy = student_policy("smolvla")  # noqa: N806

    # LeRobot loads a plain SmolVLA non-strictly: a student must not silently lose phi_s (the naive step)
    broken = tmp_path / "no_phi_s"
    shutil.copytree(student, broken)
    tensors = load_file(broken / "model.safetensors")
    save_file(
        {name: value for name, value in tensors.items() if "target_time_embedding" not in name},
        broken / "model.safetensors",
    )
    with pytest.raises(RuntimeError, match="target_time_embedding"):
        SnapFlowSmolVLAPolicy.from_pretrained(broken)
    with pytest.raises(CheckpointError, match="target_time_embedding"):
        load_distilled(broken)

    unknown = tmp_path / "unknown_mode"
    shutil.copytree(student, unknown)
    config = json.loads((unknown / "config.json").read_text())
    (unknown / "config.json").write_text(json.dumps({**config, "sampling_mode": "fast-1"}))
    with pytest.raises(Exception) as raised:  # LeRobot's config parser wraps the config's own error
        SnapFlowSmolVLAPolicy.from_pretrained(unknown)
    assert "unknown sampling mode 'fast-1'" in str(raised.value.__cause__)
    with pytest.raises(CheckpointError, match="config.json does not load: unknown sampling mode 'fast-1'"):
        load_distilled(unknown)


@PLUGINS
def test_lerobots_factory_resolves_the_student_types_by_its_conventions(vlm_directory):
    from lerobot.policies.factory import get_policy_class, make_policy_config, make_pre_post_processors

    from snapflow.adapters.lerobot.plugin import student_policy
    from snapflow.adapters.lerobot_types import LEROBOT_POLICY_TYPES

    for base_type, declared in LEROBOT_POLICY_TYPES.items():
        assert get_policy_class(declared.student_type) is student_policy(base_type)
    local = dict(vlm_model_name=str(vlm_directory), device="cpu")  # the tokenizer processor reads it
    config = make_policy_config("snapflow_smolvla", sampling_mode="teacher-4", **local)
    assert config.mode.num_steps == 4 and not config.mode.jump
    preprocessor, postprocessor = make_pre_post_processors(config)  # built fresh: SmolVLA's own steps
    assert [type(step).__name__ for step in preprocessor.steps] == [
        type(step).__name__ for step in make_pre_post_processors(make_policy_config("smolvla", **local))[0].steps
    ]


@pytest.mark.slow
@PLUGINS
@pytest.mark.parametrize("policy_type", ["pi0", "pi05"])
def test_lerobot_eval_runs_a_distilled_pi_student_in_metaworld(policy_type, vlm_directory, tmp_path, monkeypatch):
    """LeRobot's own ``lerobot-eval`` entry point, in this process: a tiny pi policy loads only while its PaliGemma
    config builders are swapped for tiny ones, which a subprocess would not have (it would build the 2B model)."""
    from lerobot.envs import metaworld as lerobot_metaworld
    from lerobot.scripts import lerobot_eval

    from tests.lerobot_tiny import save_tiny_pi_student, tiny_pi_configs

    # the features LeRobot's Meta-World env gives: a 4-D agent state and one 480-px observation.image
    student = save_tiny_pi_student(policy_type, vlm_directory, tmp_path / "student", 4, "observation.image", 480)
    assert json.loads((student / "config.json").read_text())["type"] == f"snapflow_{policy_type}"
    arguments = [f"--policy.path={student}", "--policy.device=cpu", "--env.type=metaworld", "--env.task=reach-v3"]
    arguments += ["--eval.n_episodes=1", "--eval.batch_size=1"]
    monkeypatch.setattr(sys, "argv", ["lerobot-eval", *arguments, f"--output_dir={tmp_path / 'eval'}"])
    monkeypatch.setenv("MUJOCO_GL", os.environ.get("MUJOCO_GL", "egl"))
    # LeRobot's Meta-World episode is 500 steps whatever --env.episode_length says: 16 show the chunks as well
    init = lerobot_metaworld.MetaworldEnv.__init__
    monkeypatch.setattr(lerobot_metaworld.MetaworldEnv, "__init__", _with(init, _max_episode_steps=16))
    with tiny_pi_configs(policy_type):
        model_class = type(load_distilled(student).policy.model)
        passes = []
        denoise_step = model_class.denoise_step
        monkeypatch.setattr(model_class, "denoise_step", lambda *a, **k: passes.append(1) or denoise_step(*a, **k))
        lerobot_eval.main()
    info = json.loads((tmp_path / "eval" / "eval_info.json").read_text())
    assert info["overall"]["n_episodes"] == 1 and 0 <= info["overall"]["pc_success"] <= 100
    n_action_steps = json.loads((student / "config.json").read_text())["n_action_steps"]
    assert len(passes) == -(-16 // n_action_steps), "one denoising pass a chunk: the distilled one-step student"


def _with(init, **attributes):
    """``init`` followed by setting ``attributes`` on the new object."""

    def patched(self, *args, **kwargs) -> None:
        init(self, *args, **kwargs)
        vars(self).update(attributes)

    return patched


@PLUGINS
@pytest.mark.parametrize("base_type", ["smolvla", "pi0", "pi05", "xvla", "multi_task_dit"])
def test_each_student_type_resolves_as_lerobots_own_policy_tests_expect(base_type):
    """What LeRobot checks of a policy type, by type name alone: its config and policy classes (the policy's
    ``config`` annotation a class the config is an instance of), the defaults, and a processor factory."""
    import inspect

    from lerobot.policies.factory import get_policy_class, make_policy_config

    from snapflow.adapters.lerobot.plugin import SnapFlowSampling, student_processors
    from snapflow.adapters.lerobot_types import lerobot_policy_type

    student_type = lerobot_policy_type(base_type).student_type
    policy_class = get_policy_class(student_type)
    config = make_policy_config(student_type)
    annotation = inspect.signature(policy_class.__init__).parameters["config"].annotation
    assert inspect.isclass(annotation) and isinstance(config, annotation) and policy_class.config_class is annotation
    assert isinstance(config, SnapFlowSampling) and config.type == student_type and config.base_type == base_type
    assert config.sampling_mode == "snapflow-1" and policy_class.name == student_type
    assert callable(student_processors(base_type))


@PLUGINS
def test_a_multi_task_dit_student_asked_for_chunks_on_their_own_reads_each_calls_observation(clip_directory, tmp_path):
    """LeRobot's policy server calls ``predict_action_chunk`` without ``select_action``: where multi-task DiT reads its
    observation from queues only ``select_action`` fills, each call's own observation is read (not an earlier one's),
    and the chunk is the one ``select_action`` makes from it at an episode's start, with the same noise."""
    from lerobot.policies.factory import get_policy_class

    from tests.lerobot_tiny_multi_task_dit import save_tiny_multi_task_dit_student

    folder = save_tiny_multi_task_dit_student(clip_directory, tmp_path / "student")
    policy = get_policy_class("snapflow_multi_task_dit").from_pretrained(str(folder)).eval()
    tokens = {"observation.language.tokens": torch.ones(1, 16, dtype=torch.long)}
    tokens["observation.language.attention_mask"] = torch.ones(1, 16, dtype=torch.bool)

    def observation(value: float) -> dict[str, torch.Tensor]:
        state, image = torch.full((1, 6), value), torch.full((1, 3, 32, 32), value)
        return {"observation.state": state, "observation.images.top": image, **tokens, "action": None}

    def chunk(value: float, by_select_action: bool = False) -> torch.Tensor:
        torch.manual_seed(0)
        if not by_select_action:
            return policy.predict_action_chunk(observation(value))
        policy.reset()
        batch = {key: item for key, item in observation(value).items() if key != "action"}
        return torch.stack([policy.select_action(batch) for _ in range(policy.config.n_action_steps)], dim=1)

    first, second = chunk(0.0), chunk(0.5)
    assert not torch.allclose(first, second)  # the second call read its own observation
    assert torch.equal(second, chunk(0.5, by_select_action=True))
    assert torch.equal(first, chunk(0.0))
