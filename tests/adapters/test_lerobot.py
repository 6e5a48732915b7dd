"""SnapFlow on LeRobot's SmolVLAPolicy (lerobot 0.4.4 and newer), PI0Policy and PI05Policy (lerobot >= 0.5),
each built offline at tiny size."""

from __future__ import annotations

import contextlib
from importlib.metadata import version

import pytest
import torch

pytest.importorskip("lerobot", reason="LeRobot is installed by the README's test command; this environment lacks it")

from packaging.version import Version  # noqa: E402

from snapflow import NAIVE_1, SNAPFLOW_1, SamplingMode, SnapFlowObjective, sample_actions  # noqa: E402
from snapflow.adapters.lerobot import LeRobotFlowPolicy, load_distilled, save_distilled, wrap_policy  # noqa: E402
from snapflow.training.checkpoint import CheckpointError  # noqa: E402
from tests.lerobot_tiny import build_tiny_pi, build_tiny_smolvla, tiny_batch, tiny_pi_configs, write_tiny_smolvlm  # noqa: E402

LEROBOT = Version(version("lerobot"))
PI_SKIP = pytest.mark.skipif(
    LEROBOT < Version("0.5"),
    reason=f"LeRobot's pi0 / pi0.5 need lerobot >= 0.5 (Python >= 3.12, stock transformers); lerobot {LEROBOT} is installed",
)
POLICY_TYPES = ["smolvla", pytest.param("pi0", marks=PI_SKIP), pytest.param("pi05", marks=PI_SKIP)]


@pytest.fixture(scope="module")
def vlm_directory(tmp_path_factory):
    return write_tiny_smolvlm(tmp_path_factory.mktemp("tiny_smolvlm"))


@pytest.fixture(params=POLICY_TYPES)
def policy_type(request):
    return request.param


@pytest.fixture
def build(policy_type, vlm_directory):
    """A factory of fresh, identically initialised tiny LeRobot policies of one type."""
    if policy_type == "smolvla":
        return lambda: build_tiny_smolvla(vlm_directory)
    return lambda: build_tiny_pi(policy_type)


@pytest.fixture
def tiny_sizes(policy_type):
    """What loading a tiny policy back needs: pi0 / pi0.5 rebuild from their config at tiny size only inside it."""
    return contextlib.nullcontext() if policy_type == "smolvla" else tiny_pi_configs(policy_type)


def _model_inputs(policy, batch):
    """What each LeRobot policy's ``predict_action_chunk`` hands its model, written out per policy."""
    language = batch["observation.language.tokens"], batch["observation.language.attention_mask"]
    if policy.config.type == "smolvla":
        return *policy.prepare_images(batch), *language, policy.prepare_state(batch)
    state = (policy.prepare_state(batch),) if policy.config.type == "pi0" else ()  # pi0.5's state is in its prompt
    return *policy._preprocess_images(batch), *language, *state


def _lerobot_sample(policy, batch, noise, steps):
    """LeRobot's own Euler sampler on the (possibly wrapped) policy: s = t throughout."""
    policy.config.num_steps = policy.config.num_inference_steps = steps  # SmolVLA's name, pi0's name
    with torch.no_grad():
        return policy.model.sample_actions(*_model_inputs(policy, batch), noise=noise)


def _randomise_target_time(adapter: LeRobotFlowPolicy) -> None:
    with torch.no_grad():
        for parameter in adapter.target_time_embedding.linear_out.parameters():
            parameter.normal_(0, 0.2)


def test_unsupported_policies_and_lerobot_versions_are_named():
    from snapflow.adapters.lerobot import PI05FlowPolicy
    from snapflow.adapters.lerobot.registry import adapter_class

    with pytest.raises(ValueError, match="pi0, pi05, smolvla policies, not 'act'"):
        adapter_class("act")
    if LEROBOT < Version("0.5"):
        with pytest.raises(ValueError, match=f"pi05 adapter needs lerobot >= 0.5 .* lerobot {LEROBOT} is installed"):
            adapter_class("pi05")
    else:
        assert adapter_class("pi05") is PI05FlowPolicy


def test_wrapping_changes_no_output_bit_at_init(build):
    reference = build()
    adapter = wrap_policy(build())
    batch, noise = tiny_batch(), torch.randn(4, 4, 4)
    for steps in (1, 2):
        expected = _lerobot_sample(reference, batch, noise, steps)
        assert torch.equal(sample_actions(adapter, batch, noise, SamplingMode(steps, jump=False)), expected)
    # phi_s starts at zero, so even the jump (s = 0) reproduces LeRobot's one-step sample bit for bit
    assert torch.equal(sample_actions(adapter, batch, noise, SNAPFLOW_1), _lerobot_sample(reference, batch, noise, 1))


def test_target_time_changes_only_the_jump_and_leaves_lerobot_sampling_as_the_teacher(build):
    adapter = wrap_policy(build())
    _randomise_target_time(adapter)
    batch, noise = tiny_batch(), torch.randn(4, 4, 4)
    # LeRobot's own sampler passes a (B,) time, read as s = t: it is exactly our teacher mode
    assert torch.equal(sample_actions(adapter, batch, noise, NAIVE_1), _lerobot_sample(adapter.policy, batch, noise, 1))
    assert not torch.allclose(sample_actions(adapter, batch, noise, SNAPFLOW_1), sample_actions(adapter, batch, noise, NAIVE_1))


def test_loss_equals_a_hand_computation_from_the_policys_own_outputs(build):
    adapter = wrap_policy(build())
    _randomise_target_time(adapter)
    policy = adapter.policy
    batch = tiny_batch()
    actions = policy.prepare_action(batch)
    noise, time = torch.randn(4, 4, 4), torch.rand(2)
    output = SnapFlowObjective()(adapter, batch, actions, noise=noise, time=time)

    fm_rows = {key: value[:2] for key, value in batch.items()}
    sc_rows = {key: value[2:] for key, value in batch.items()}
    # FM branch: LeRobot's own joint training forward returns the elementwise squared errors
    fm = policy.model.forward(*_model_inputs(policy, fm_rows), actions[:2], noise[:2], time).mean()
    # consistency target: two LeRobot Euler steps from x_1 land on x_1 - target
    target = noise[2:] - _lerobot_sample(policy, sc_rows, noise[2:], 2)
    jump = adapter.velocity(noise[2:], torch.ones(2), torch.zeros(2), adapter.encode(sc_rows))
    sc = (jump - target).pow(2).mean()
    assert torch.allclose(output.flow_matching_loss, fm, atol=1e-5)
    assert torch.allclose(output.consistency_loss, sc, atol=1e-5)
    assert torch.allclose(output.loss, 0.5 * fm + 0.5 * 0.1 * sc, atol=1e-5)


def test_gradients_reach_only_the_expert_and_the_embedding(build):
    adapter = wrap_policy(build())
    trainable = {id(p) for p in adapter.expert_parameters()}
    for parameter in adapter.parameters():
        parameter.requires_grad_(id(parameter) in trainable)
    batch = tiny_batch()
    SnapFlowObjective()(adapter, batch, adapter.policy.prepare_action(batch)).loss.backward()
    for name, parameter in adapter.policy.named_parameters():
        if id(parameter) in trainable:
            assert parameter.grad is not None, f"{name} got no gradient"
        else:
            assert parameter.grad is None, f"{name} is frozen but got a gradient"
    # at step 0 phi_s's last layer is zero, so only it receives a non-zero gradient; Linear1 follows a step later
    assert adapter.target_time_embedding.linear_in.weight.grad is not None
    assert adapter.target_time_embedding.linear_out.weight.grad.abs().sum() > 0
    expert = adapter.expert_modules()[0]
    assert sum(p.grad.abs().sum() for p in expert.parameters() if p.grad is not None) > 0


@PI_SKIP
@pytest.mark.parametrize("policy_type", ["pi0", "pi05"])
def test_gradient_checkpointing_gives_the_same_gradients(policy_type):
    """s is an argument of the recomputed functions, not hook state, so checkpointing recomputes the same values;
    and the frozen prefix pass keeps its cache although Hugging Face drops it when checkpointing in training."""
    gradients = []
    for checkpointing in (False, True):
        adapter = wrap_policy(build_tiny_pi(policy_type))
        _randomise_target_time(adapter)
        if checkpointing:
            adapter.policy.model.gradient_checkpointing_enable()
        trainable = {id(p) for p in adapter.expert_parameters()}
        for parameter in adapter.parameters():
            parameter.requires_grad_(id(parameter) in trainable)
        adapter.train()
        batch, generator = tiny_batch(), torch.Generator().manual_seed(0)
        noise, time = torch.randn(4, 4, 4, generator=generator), torch.rand(2, generator=generator)
        SnapFlowObjective()(adapter, batch, adapter.policy.prepare_action(batch), noise=noise, time=time).loss.backward()
        gradients.append({name: p.grad for name, p in adapter.named_parameters() if p.grad is not None})
    assert gradients[0].keys() == gradients[1].keys() and len(gradients[0]) > 0
    for name, gradient in gradients[0].items():
        assert torch.allclose(gradient, gradients[1][name], atol=1e-6), name


def test_distillation_lowers_the_consistency_loss(build):
    adapter = wrap_policy(build())
    parameters = adapter.expert_parameters()
    trainable = {id(p) for p in parameters}
    for parameter in adapter.parameters():
        parameter.requires_grad_(id(parameter) in trainable)
    batch = tiny_batch(batch_size=8)
    actions = adapter.policy.prepare_action(batch)
    # a random tiny teacher has a large FM loss and a small consistency loss: weight the latter up so that a few
    # steps show it falling before the FM updates move the teacher's own two-step target
    objective = SnapFlowObjective(consistency_weight=1.0)
    noise, time = torch.randn(8, 4, 4, generator=torch.Generator().manual_seed(1)), torch.rand(4)

    def consistency() -> float:
        with torch.no_grad():
            return objective(adapter, batch, actions, noise=noise, time=time).consistency_loss.item()

    before = consistency()
    optimizer = torch.optim.AdamW(parameters, lr=1e-3)
    generator = torch.Generator().manual_seed(2)
    for _ in range(15):
        optimizer.zero_grad()
        objective(adapter, batch, actions, generator=generator).loss.backward()
        optimizer.step()
    assert consistency() < 0.8 * before


def test_save_reload_and_one_step_sampling(build, tiny_sizes, tmp_path):
    adapter = wrap_policy(build())
    _randomise_target_time(adapter)
    batch, noise = tiny_batch(), torch.randn(4, 4, 4)
    expected = sample_actions(adapter, batch, noise, SNAPFLOW_1)
    save_distilled(adapter, tmp_path / "distilled")
    with tiny_sizes:
        reloaded = load_distilled(tmp_path / "distilled")
    assert torch.equal(sample_actions(reloaded, batch, noise, SNAPFLOW_1), expected)
    assert torch.equal(sample_actions(reloaded, batch, noise, SamplingMode(10, jump=False)),
                       sample_actions(adapter, batch, noise, SamplingMode(10, jump=False)))
    with pytest.raises(CheckpointError, match="not a SnapFlow-distilled"):
        load_distilled(tmp_path)
    # the adapter's own state dict holds each tensor once, so generic safetensors checkpoints work too
    from safetensors.torch import save_file

    save_file({k: v.contiguous() for k, v in adapter.state_dict().items()}, tmp_path / "adapter.safetensors")


def test_lerobot_action_api_samples_one_step_by_default_and_the_teacher_on_request(build, tiny_sizes, tmp_path):
    adapter = wrap_policy(build())
    _randomise_target_time(adapter)
    save_distilled(adapter, tmp_path / "distilled")
    with tiny_sizes:
        reloaded = load_distilled(tmp_path / "distilled")
    batch, noise = tiny_batch(), torch.randn(4, 4, 4)
    one_step = reloaded.policy.predict_action_chunk(batch, noise=noise)
    assert torch.equal(one_step, sample_actions(adapter, batch, noise, SNAPFLOW_1))
    assert reloaded.policy.select_action(batch).shape == (4, 4)  # LeRobot's queue of n_action_steps actions
    reloaded.use_sampling_mode(SamplingMode(10, jump=False))
    teacher = reloaded.policy.predict_action_chunk(batch, noise=noise)
    assert torch.equal(teacher, sample_actions(adapter, batch, noise, SamplingMode(10, jump=False)))
    assert not torch.allclose(teacher, one_step)


def test_cli_distills_a_saved_smolvla_on_a_local_lerobot_dataset(vlm_directory, tmp_path, capsys):
    from snapflow.cli import main
    from tests.lerobot_tiny import write_tiny_dataset

    dataset = write_tiny_dataset(tmp_path / "dataset")
    build_tiny_smolvla(vlm_directory).save_pretrained(tmp_path / "teacher")
    arguments = ["distill", "--policy", str(tmp_path / "teacher"), "--dataset", str(dataset), "--repo-id", "local/tiny",
                 "--output", str(tmp_path / "run"), "--steps", "3", "--batch-size", "4", "--learning-rate", "1e-3", "--no-progress"]
    assert main(arguments) == 0
    assert (tmp_path / "run" / "checkpoints" / "step_0000003" / "policy.safetensors").is_file()
    distilled = load_distilled(tmp_path / "run" / "lerobot_policy")
    assert distilled.target_time_embedding.linear_out.weight.abs().sum() > 0, "phi_s must have trained"
    teacher = build_tiny_smolvla(vlm_directory)
    for name, parameter in teacher.model.vlm_with_expert.vlm.named_parameters():
        assert torch.equal(parameter, distilled.policy.model.vlm_with_expert.vlm.get_parameter(name)), f"frozen {name} moved"
    # the exported folder carries LeRobot's processors: raw observations in, 1-NFE actions out
    from lerobot.policies.factory import make_pre_post_processors

    preprocessor, postprocessor = make_pre_post_processors(
        distilled.policy.config, pretrained_path=str(tmp_path / "run" / "lerobot_policy"),
        preprocessor_overrides={"tokenizer_processor": {"tokenizer_name": str(vlm_directory)}, "device_processor": {"device": "cpu"}},
    )
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    frame = LeRobotDataset("local/tiny", root=dataset)[0]
    raw = {key: value[None] if torch.is_tensor(value) else [value] for key, value in frame.items()}
    actions = postprocessor(distilled.policy.predict_action_chunk(preprocessor(raw)))
    assert actions.shape == (1, 4, 4) and torch.isfinite(actions).all()

    assert main(arguments + ["--resume"]) == 0  # already at its last step: resumes and stops cleanly
    assert main(["distill", "--policy", "x", "--data", "y", "--output", str(tmp_path / "bad"), "--no-progress"]) == 2
    assert "either --teacher and --data" in capsys.readouterr().err
    # a policy whose state is shorter than the dataset's is named before any step (LeRobot would pad silently)
    build_tiny_smolvla(vlm_directory, state_dim=5).save_pretrained(tmp_path / "narrow")
    narrow = [str(tmp_path / "narrow") if a == str(tmp_path / "teacher") else str(tmp_path / "narrow_run") if a == str(tmp_path / "run") else a
              for a in arguments]
    assert main(narrow) == 2
    assert "observation.state: the dataset has shape (6,), the policy expects (5,)" in capsys.readouterr().err
    assert not (tmp_path / "narrow_run" / "checkpoints").exists()
    # NaN in a dataset, which LeRobot records without complaint, is refused before any step
    nan_dataset = write_tiny_dataset(tmp_path / "nan_dataset", repo_id="local/nan", nan_at=17)
    poisoned = [str(nan_dataset) if a == str(dataset) else "local/nan" if a == "local/tiny" else
                str(tmp_path / "nan_run") if a == str(tmp_path / "run") else a for a in arguments]
    assert main(poisoned) == 2
    assert "action holds NaN or inf (first at frame 17, dimension 1)" in capsys.readouterr().err
    assert not (tmp_path / "nan_run" / "checkpoints").exists()


@PI_SKIP
@pytest.mark.parametrize("policy_type", ["pi0", "pi05"])
def test_cli_distills_a_saved_pi_policy_on_a_local_lerobot_dataset(policy_type, vlm_directory, tmp_path):
    from lerobot.datasets.lerobot_dataset import LeRobotDataset
    from lerobot.policies.factory import make_pre_post_processors

    from snapflow.cli import main
    from tests.lerobot_tiny import cache_as_hub_repo, write_tiny_dataset

    # LeRobot's pi processors load PaliGemma's tokenizer by hub id: the tiny one stands in for it, offline
    cache_as_hub_repo(vlm_directory, "google/paligemma-3b-pt-224")
    dataset = write_tiny_dataset(tmp_path / "dataset")
    build_tiny_pi(policy_type).save_pretrained(tmp_path / "teacher")
    with tiny_pi_configs(policy_type):
        assert main(["distill", "--policy", str(tmp_path / "teacher"), "--dataset", str(dataset), "--repo-id", "local/tiny",
                     "--output", str(tmp_path / "run"), "--steps", "3", "--batch-size", "4", "--learning-rate", "1e-3",
                     "--no-progress"]) == 0
        distilled = load_distilled(tmp_path / "run" / "lerobot_policy")
    assert distilled.target_time_embedding.linear_out.weight.abs().sum() > 0, "phi_s must have trained"
    teacher = build_tiny_pi(policy_type)
    for name, parameter in teacher.model.paligemma_with_expert.paligemma.named_parameters():
        assert torch.equal(parameter, distilled.policy.model.paligemma_with_expert.paligemma.get_parameter(name)), f"frozen {name} moved"
    assert not torch.equal(teacher.model.action_out_proj.weight, distilled.policy.model.action_out_proj.weight)
    # the export carries LeRobot's processors: a raw dataset frame in, 1-NFE actions in the dataset's units out
    preprocessor, postprocessor = make_pre_post_processors(distilled.policy.config, pretrained_path=str(tmp_path / "run" / "lerobot_policy"))
    frame = LeRobotDataset("local/tiny", root=dataset)[0]
    raw = {key: value[None] if torch.is_tensor(value) else [value] for key, value in frame.items()}
    actions = postprocessor(distilled.policy.predict_action_chunk(preprocessor(raw)))
    assert actions.shape == (1, 4, 4) and torch.isfinite(actions).all()


def test_cli_evaluates_a_distilled_smolvla_in_lerobots_own_metaworld(vlm_directory, tmp_path, capsys):
    import json

    from lerobot.policies.factory import make_pre_post_processors

    from snapflow.cli import main

    # a distilled SmolVLA with the features LeRobot's Meta-World env produces, saved with its processors
    policy = build_tiny_smolvla(vlm_directory, state_dim=4, image_key="observation.image", image_size=480)
    adapter = wrap_policy(policy)
    _randomise_target_time(adapter)
    directory = save_distilled(adapter, tmp_path / "distilled")
    unit = {"mean": torch.zeros(4), "std": torch.ones(4)}
    for processor in make_pre_post_processors(policy.config, dataset_stats={"observation.state": unit, "action": unit}):
        processor.save_pretrained(directory)

    output = tmp_path / "eval"
    arguments = ["eval", "--lerobot-env", "metaworld", "--env-task", "reach-v3", "--policy", str(directory), "--episodes", "2",
                 "--n-envs", "2", "--n-act", "2", "--modes", "snapflow-1,teacher-2", "--max-episode-steps", "12",
                 "--output-dir", str(output), "--no-progress"]
    assert main(arguments) == 0
    report = json.loads((output / "report.json").read_text())
    assert report["policy_type"] == "smolvla" and report["n_action_steps"] == 2 and report["task"] == "reach-v3"
    assert list(report["modes"]) == ["snapflow-1", "teacher-2"]
    rewards = []
    for name, nfe in (("snapflow-1", 1), ("teacher-2", 2)):
        info = report["modes"][name]
        assert info["nfe"] == nfe and info["overall"]["n_episodes"] == 2 and 0 <= info["overall"]["pc_success"] <= 100
        assert json.loads((output / name / "eval_info.json").read_text())["overall"] == info["overall"]  # lerobot-eval's file
        rewards.append(info["overall"]["avg_sum_reward"])
    assert rewards[0] != rewards[1], "the two sampling modes must drive the robot differently"
    assert "| snapflow-1 | 1 |" in capsys.readouterr().out

    def changed(option: str, value: str) -> list[str]:
        changed = list(arguments)
        changed[changed.index(option) + 1] = value
        return changed

    assert main(changed("--lerobot-env", "nowhere")) == 2
    assert "unknown LeRobot environment 'nowhere'" in capsys.readouterr().err
    assert main(changed("--n-act", "9")) == 2  # more actions per chunk than the chunk holds
    assert "n_action_steps must be between 1" in capsys.readouterr().err


def test_bench_cli_times_a_distilled_lerobot_policy(build, tiny_sizes, policy_type, tmp_path):
    import json

    from snapflow.cli import main

    directory = save_distilled(wrap_policy(build()), tmp_path / "distilled")
    output = tmp_path / "bench"
    with tiny_sizes:
        assert main(["bench", "--policy", str(directory), "--warmup", "1", "--repeats", "2", "--no-profile", "--output-dir", str(output)]) == 0
    report = json.loads((output / "bench.json").read_text())
    assert report["details"]["policy_type"] == policy_type
    assert 0 < report["details"]["expert_parameters"] < report["details"]["parameters"]
    assert report["latency"]["modes"]["snapflow-1"]["nfe"] == 1 and report["latency"]["prefix"]["repeats"] == 2


def test_dataset_image_channels_are_read_from_either_layout_even_without_names():
    from types import SimpleNamespace

    from lerobot.configs.types import FeatureType, PolicyFeature

    from snapflow.experiments.lerobot import check_dataset_features

    config = SimpleNamespace(input_features={"image": PolicyFeature(type=FeatureType.VISUAL, shape=(3, 64, 64))}, output_features={})
    check_dataset_features(config, {"image": {"shape": (3, 32, 32), "names": None}}, "local/x")  # channels first, unnamed
    check_dataset_features(config, {"image": {"shape": (32, 32, 3), "names": ["height", "width", "channels"]}}, "local/x")
    with pytest.raises(ValueError, match="image: the dataset's images have 4 channels, the policy expects 3"):
        check_dataset_features(config, {"image": {"shape": (32, 32, 4), "names": ["height", "width", "channels"]}}, "local/x")
