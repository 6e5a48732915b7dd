"""LeRobot's SmolVLAPolicy (lerobot 0.4.4 and newer), PI0Policy and PI05Policy (lerobot >= 0.5), each built offline at
tiny size: what is not the per-adapter contract (tests/adapters/lerobot_contract.py) — the registry's refusals, gradient
checkpointing, and the CLI end to end (distill on a local LeRobotDataset, eval in LeRobot's own Meta-World)."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest
import torch

pytest.importorskip("lerobot", reason="LeRobot is installed by the README's test command; this environment lacks it")

from packaging.version import Version  # noqa: E402

from snapflow import SnapFlowObjective  # noqa: E402
from snapflow.adapters.lerobot import load_distilled, wrap_policy  # noqa: E402
from snapflow.inference.deploy import DEPLOY_ACTION_BOUND  # noqa: E402
from tests.lerobot_tiny import (  # noqa: E402
    LEROBOT,
    PI_SKIP,
    TRANSFORMERS,
    build_tiny_pi,
    build_tiny_smolvla,
    randomise_target_time,
    tiny_batch,
    tiny_pi_configs,
)


def test_unsupported_policies_and_lerobot_versions_are_named():
    from snapflow.adapters.lerobot import PI05FlowPolicy
    from snapflow.adapters.lerobot.registry import adapter_class

    with pytest.raises(ValueError, match="pi0, pi05, smolvla, xvla policies, not 'act': a transformer that regresses"):
        adapter_class("act")
    if LEROBOT < Version(PI05FlowPolicy.minimum_lerobot):
        with pytest.raises(ValueError, match=f"pi05 adapter needs lerobot >= 0.5 .* lerobot {LEROBOT} is installed"):
            adapter_class("pi05")
    else:
        assert adapter_class("pi05") is PI05FlowPolicy


def test_every_policy_type_the_installed_lerobot_knows_is_distilled_or_refused_with_why():
    """A type a new LeRobot adds cannot go unnoticed: each is declared, or named with why it is not distilled."""
    import importlib

    import lerobot.policies
    from lerobot.configs.policies import PreTrainedConfig

    from snapflow.adapters.lerobot_types import LEROBOT_POLICY_TYPES, NOT_DISTILLED

    # every config module LeRobot ships registers its type on import, whatever another test imported before (some
    # policy folders have no __init__.py, which pkgutil does not walk into)
    policies = Path(lerobot.policies.__path__[0])
    for path in policies.rglob("configuration_*.py"):
        try:
            importlib.import_module(
                ".".join(("lerobot", "policies", *path.relative_to(policies).with_suffix("").parts))
            )
        except ImportError:  # a type whose optional dependencies are not installed registers nothing
            continue

    lerobots_own = {  # beside LeRobot's own types: the student types and any a test declared
        name
        for name, config in PreTrainedConfig.get_known_choices().items()
        if config.__module__.startswith("lerobot.policies.")
    }
    assert len(lerobots_own) >= 6 and lerobots_own <= set(LEROBOT_POLICY_TYPES) | set(NOT_DISTILLED)
    assert not set(LEROBOT_POLICY_TYPES) & set(NOT_DISTILLED)


@pytest.mark.parametrize(("policy_type", "why"), [("pi0_fast", "autoregressive"), ("diffusion", "DDPM / DDIM")])
def test_a_policy_folder_of_a_type_snapflow_does_not_distil_is_refused_with_why(policy_type, why, tmp_path, capsys):
    from snapflow.cli import main

    (tmp_path / "policy").mkdir()
    (tmp_path / "policy" / "config.json").write_text(f'{{"type": "{policy_type}"}}')
    arguments = ["eval", "--policy", str(tmp_path / "policy"), "--episodes", "1", "--output", str(tmp_path / "out")]
    assert main(arguments) == 2
    error = capsys.readouterr().err
    assert f"not '{policy_type}': " in error and why in error
    assert not (tmp_path / "out").exists()


@pytest.mark.slow
@PI_SKIP
@pytest.mark.parametrize("policy_type", ["pi0", "pi05"])
def test_gradient_checkpointing_gives_the_same_gradients(policy_type):
    """s is an argument of the recomputed functions, not hook state, so checkpointing recomputes the same values;
    and the frozen prefix pass keeps its cache although Hugging Face drops it when checkpointing in training."""
    gradients = []
    for checkpointing in (False, True):
        adapter = wrap_policy(build_tiny_pi(policy_type))
        randomise_target_time(adapter)
        if checkpointing:
            adapter.policy.model.gradient_checkpointing_enable()
        trainable = {id(p) for p in adapter.expert_parameters()}
        for parameter in adapter.parameters():
            parameter.requires_grad_(id(parameter) in trainable)
        adapter.train()
        batch, generator = tiny_batch(), torch.Generator().manual_seed(0)
        noise, time = torch.randn(4, 4, 4, generator=generator), torch.rand(2, generator=generator)
        SnapFlowObjective()(
            adapter, batch, adapter.policy.prepare_action(batch), noise=noise, time=time
        ).loss.backward()
        gradients.append({name: p.grad for name, p in adapter.named_parameters() if p.grad is not None})
    assert gradients[0].keys() == gradients[1].keys() and len(gradients[0]) > 0
    for name, gradient in gradients[0].items():
        assert torch.allclose(gradient, gradients[1][name], atol=1e-6), name


def test_a_saved_teacher_opens_with_the_same_weights_each_time(vlm_directory, tmp_path):
    """A LeRobot teacher folder holds no phi_s: each opening adds one, the same whatever the global random state, so
    an evaluation's episode log is resumed by a later opening of that teacher (and by no other policy)."""
    from snapflow.adapters.lerobot.checkpoint import save_teacher
    from snapflow.evaluation.pipeline import weights_digest
    from snapflow.sources import open_policy

    teacher = save_teacher(wrap_policy(build_tiny_smolvla(vlm_directory)), tmp_path / "teacher", 0.0)
    digests = []
    for seed in (1, 2):
        torch.manual_seed(seed)
        digests.append(weights_digest(open_policy(teacher).policy))
    assert digests[0] == digests[1]
    other = save_teacher(wrap_policy(build_tiny_smolvla(vlm_directory, seed=1)), tmp_path / "other", 0.0)
    assert weights_digest(open_policy(other).policy) != digests[0]


def _distill_arguments(tmp_path, dataset) -> list[str]:
    """``snapflow distill`` of the teacher saved at tmp_path/teacher on ``dataset``: three tiny steps into tmp_path/run."""
    return [
        "distill",
        "--policy",
        str(tmp_path / "teacher"),
        "--dataset",
        str(dataset),
        "--repo-id",
        "local/tiny",
        "--output",
        str(tmp_path / "run"),
        "--steps",
        "3",
        "--batch-size",
        "4",
        "--learning-rate",
        "1e-3",
        "--no-progress",
    ]


@pytest.mark.slow
def test_cli_distills_a_saved_smolvla_on_a_local_lerobot_dataset(vlm_directory, tmp_path, capsys):
    from snapflow.cli import main
    from tests.lerobot_tiny import write_tiny_dataset

    dataset = write_tiny_dataset(tmp_path / "dataset")
    build_tiny_smolvla(vlm_directory).save_pretrained(tmp_path / "teacher")
    arguments = _distill_arguments(tmp_path, dataset)
    kept = ["--keep-progress", str(tmp_path / "kept")]
    assert main(arguments + kept) == 0
    assert (tmp_path / "run" / "checkpoints" / "step_0000003" / "policy.safetensors").is_file()
    distilled = load_distilled(tmp_path / "run" / "lerobot_policy")
    assert distilled.target_time_embedding.linear_out.weight.abs().sum() > 0, "phi_s must have trained"
    teacher = build_tiny_smolvla(vlm_directory)
    for name, parameter in teacher.model.vlm_with_expert.vlm.named_parameters():
        assert torch.equal(parameter, distilled.policy.model.vlm_with_expert.vlm.get_parameter(name)), (
            f"frozen {name} moved"
        )
    # the exported folder carries LeRobot's processors: raw observations in, 1-NFE actions out
    from lerobot.policies.factory import make_pre_post_processors

    preprocessor, postprocessor = make_pre_post_processors(
        distilled.policy.config,
        pretrained_path=str(tmp_path / "run" / "lerobot_policy"),
        preprocessor_overrides={
            "tokenizer_processor": {"tokenizer_name": str(vlm_directory)},
            "device_processor": {"device": "cpu"},
        },
    )
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    frame = LeRobotDataset("local/tiny", root=dataset)[0]
    raw = {key: value[None] if torch.is_tensor(value) else [value] for key, value in frame.items()}
    actions = postprocessor(distilled.policy.predict_action_chunk(preprocessor(raw)))
    assert actions.shape == (1, 4, 4) and torch.isfinite(actions).all()

    assert main(arguments + ["--resume"]) == 0  # already at its last step: resumes and stops cleanly
    # on a machine with only the kept checkpoint, the finished run is continued at its last step: exported as it was
    moved = [str(tmp_path / "moved") if argument == str(tmp_path / "run") else argument for argument in arguments]
    capsys.readouterr()
    assert main(moved + kept + ["--resume"]) == 0
    out = capsys.readouterr().out
    assert "continuing from the one kept in" in out and "moved at step 3" in out, "no step trained again"
    again = load_distilled(tmp_path / "moved" / "lerobot_policy").state_dict()
    assert again.keys() == distilled.state_dict().keys()
    assert all(torch.equal(again[name], value) for name, value in distilled.state_dict().items())
    assert main(["distill", "--policy", "x", "--data", "y", "--output", str(tmp_path / "bad"), "--no-progress"]) == 2
    assert "either --teacher and --data" in capsys.readouterr().err
    # a policy whose state is shorter than the dataset's is named before any step (LeRobot would pad silently)
    build_tiny_smolvla(vlm_directory, state_dim=5).save_pretrained(tmp_path / "narrow")
    narrow = [
        str(tmp_path / "narrow")
        if a == str(tmp_path / "teacher")
        else str(tmp_path / "narrow_run")
        if a == str(tmp_path / "run")
        else a
        for a in arguments
    ]
    assert main(narrow) == 2
    assert "observation.state: the dataset has shape (6,), the policy expects (5,)" in capsys.readouterr().err
    assert not (tmp_path / "narrow_run" / "checkpoints").exists()
    # NaN in a dataset, which LeRobot records without complaint, is refused before any step
    nan_dataset = write_tiny_dataset(tmp_path / "nan_dataset", repo_id="local/nan", nan_at=17)
    poisoned = [
        str(nan_dataset)
        if a == str(dataset)
        else "local/nan"
        if a == "local/tiny"
        else str(tmp_path / "nan_run")
        if a == str(tmp_path / "run")
        else a
        for a in arguments
    ]
    assert main(poisoned) == 2
    assert "action holds NaN or inf (first at frame 17, dimension 1)" in capsys.readouterr().err
    assert not (tmp_path / "nan_run" / "checkpoints").exists()


def test_distilling_into_an_output_another_process_holds_is_refused_before_anything_loads(tmp_path):
    from snapflow.reporting.locks import RunLockedError
    from snapflow.training.lerobot import distill_lerobot
    from tests.locking import held_by_another_process

    dataset = tmp_path / "dataset"
    (dataset / "meta").mkdir(parents=True)
    (dataset / "meta" / "info.json").write_text("{}")  # a dataset folder, checked first (a wrong one writes nothing)
    with held_by_another_process(tmp_path / "run", "snapflow distill") as holder:
        with pytest.raises(RunLockedError, match=rf"\(pid {holder.pid}, snapflow distill\)"):
            # the policy does not exist and the dataset is empty: the refusal comes before either loads
            distill_lerobot(str(tmp_path / "no-policy"), dataset, "local/none", tmp_path / "run")


@pytest.mark.slow
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
        assert main(_distill_arguments(tmp_path, dataset)) == 0
        distilled = load_distilled(tmp_path / "run" / "lerobot_policy")
    assert distilled.target_time_embedding.linear_out.weight.abs().sum() > 0, "phi_s must have trained"
    teacher = build_tiny_pi(policy_type)
    for name, parameter in teacher.model.paligemma_with_expert.paligemma.named_parameters():
        assert torch.equal(parameter, distilled.policy.model.paligemma_with_expert.paligemma.get_parameter(name)), (
            f"frozen {name} moved"
        )
    assert not torch.equal(teacher.model.action_out_proj.weight, distilled.policy.model.action_out_proj.weight)
    # the export carries LeRobot's processors: a raw dataset frame in, 1-NFE actions in the dataset's units out
    preprocessor, postprocessor = make_pre_post_processors(
        distilled.policy.config, pretrained_path=str(tmp_path / "run" / "lerobot_policy")
    )
    frame = LeRobotDataset("local/tiny", root=dataset)[0]
    raw = {key: value[None] if torch.is_tensor(value) else [value] for key, value in frame.items()}
    actions = postprocessor(distilled.policy.predict_action_chunk(preprocessor(raw)))
    assert actions.shape == (1, 4, 4) and torch.isfinite(actions).all()


@pytest.mark.slow
def test_cli_evaluates_a_distilled_smolvla_in_lerobots_own_metaworld(vlm_directory, tmp_path, capsys):
    import json

    from snapflow.cli import main
    from tests.lerobot_tiny import save_tiny_student

    directory = save_tiny_student(vlm_directory, tmp_path / "distilled")

    output = tmp_path / "eval"
    arguments = [
        "eval",
        "--lerobot-env",
        "metaworld",
        "--env-task",
        "reach-v3",
        "--policy",
        str(directory),
        "--episodes",
        "2",
        "--n-envs",
        "2",
        "--n-act",
        "2",
        "--modes",
        "snapflow-1,teacher-2",
        "--max-episode-steps",
        "12",
        "--output",
        str(output),
        "--no-progress",
    ]
    assert main(arguments) == 0
    report = json.loads((output / "report.json").read_text())
    assert report["policy_type"] == "smolvla" and report["n_action_steps"] == 2 and report["task"] == "reach-v3"
    assert list(report["modes"]) == ["snapflow-1", "teacher-2"]
    rewards = []
    for name, nfe in (("snapflow-1", 1), ("teacher-2", 2)):
        info = report["modes"][name]
        assert info["nfe"] == nfe and info["overall"]["n_episodes"] == 2 and 0 <= info["overall"]["pc_success"] <= 100
        assert (
            json.loads((output / name / "eval_info.json").read_text())["overall"] == info["overall"]
        )  # lerobot-eval's file
        rewards.append(info["overall"]["avg_sum_reward"])
    assert rewards[0] != rewards[1], "the two sampling modes must drive the robot differently"
    assert "| snapflow-1 | 1 |" in capsys.readouterr().out

    def changed(option: str, value: str) -> list[str]:
        changed = list(arguments)
        changed[changed.index(option) + 1] = value
        return changed

    assert main(changed("--lerobot-env", "nowhere")) == 2
    assert "unknown LeRobot environment 'nowhere'" in capsys.readouterr().err
    assert main(changed("--lerobot-env", "pusht")) == 2  # LeRobot's PushT package is not installed here
    assert (
        'LeRobot\'s pusht environment needs gym_pusht, which is not installed: pip install "lerobot[pusht]"'
        in capsys.readouterr().err
    )
    assert main(changed("--n-act", "9")) == 2  # more actions per chunk than the chunk holds
    assert "n_action_steps must be between 1" in capsys.readouterr().err

    # a student as lerobot-train leaves it (its config's own label, no snapflow.json) opens as every command opens it
    trained = tmp_path / "lerobot-train-student"
    shutil.copytree(directory, trained)
    (trained / "snapflow.json").unlink()
    quick = changed("--policy", str(trained))
    quick[quick.index("--modes") + 1] = "snapflow-1"
    quick[quick.index("--output") + 1] = str(tmp_path / "eval-trained")
    assert main(quick) == 0, capsys.readouterr().err
    assert list(json.loads((tmp_path / "eval-trained" / "report.json").read_text())["modes"]) == ["snapflow-1"]
    # never distilled: its one step would be the naive one, refused as such
    config = json.loads((trained / "config.json").read_text())
    (trained / "config.json").write_text(json.dumps({**config, "distilled": False}))
    assert main(quick) == 2
    assert (
        "is not SnapFlow-distilled (a flow-matching teacher): snapflow-1 would be the naive" in capsys.readouterr().err
    )


def test_dataset_image_channels_are_read_from_either_layout_even_without_names():
    from types import SimpleNamespace

    from lerobot.configs.types import FeatureType, PolicyFeature

    from snapflow.training.lerobot import check_dataset_features

    config = SimpleNamespace(
        input_features={"image": PolicyFeature(type=FeatureType.VISUAL, shape=(3, 64, 64))}, output_features={}
    )
    check_dataset_features(
        config, {"image": {"shape": (3, 32, 32), "names": None}}, "local/x"
    )  # channels first, unnamed
    check_dataset_features(
        config, {"image": {"shape": (32, 32, 3), "names": ["height", "width", "channels"]}}, "local/x"
    )
    with pytest.raises(ValueError, match="image: the dataset's images have 4 channels, the policy expects 3"):
        check_dataset_features(
            config, {"image": {"shape": (32, 32, 4), "names": ["height", "width", "channels"]}}, "local/x"
        )


@PI_SKIP
@pytest.mark.parametrize("policy_type", ["pi0", "pi05"])
def test_the_vision_tower_runs_in_bfloat16_on_request_and_moves_the_actions_little(policy_type):
    from snapflow.benchmark.bench import one_step_actions
    from snapflow.benchmark.subjects import lerobot_subject

    with tiny_pi_configs(policy_type):
        subject = lerobot_subject(
            randomise_target_time(wrap_policy(build_tiny_pi(policy_type))), "tiny", torch.device("cpu"), torch.float32
        )
    exact = one_step_actions(subject)
    for _ in range(2):  # a second call changes nothing more
        subject.policy.run_vision_in(torch.bfloat16)
        difference = (one_step_actions(subject) - exact).abs().max().item()
    tower = subject.policy.policy.model.paligemma_with_expert.paligemma.model.vision_tower
    assert {parameter.dtype for parameter in tower.parameters()} == {torch.bfloat16}
    # bfloat16 rounding of the image features, nothing more: a change, and one within deploy's bound
    assert 0 < difference <= DEPLOY_ACTION_BOUND


@pytest.mark.skipif(TRANSFORMERS < Version("5"), reason="reproduces transformers 5's embeddings")
def test_smolvlms_vision_embeddings_without_host_syncs_are_transformers_own(vlm_directory):
    """deploy's capturable SmolVLM vision embeddings against transformers' own, on whole images (what SmolVLA hands
    them) and on padded ones (rows and columns of patches masked out)."""
    from snapflow.adapters.lerobot.smolvla import _capturable_embeddings_forward

    embeddings = build_tiny_smolvla(vlm_directory).model.vlm_with_expert.get_vlm_model().vision_model.embeddings
    capturable = _capturable_embeddings_forward(embeddings)
    side = embeddings.num_patches_per_side
    pixels = torch.randn(3, 3, side * embeddings.patch_size, side * embeddings.patch_size)
    mask = torch.ones(3, side, side, dtype=torch.bool)
    mask[1, side // 2 :, :] = False
    mask[2, :, side - 1 :] = False
    for patches in (torch.ones_like(mask), mask):
        torch.testing.assert_close(capturable(pixels, patches), embeddings(pixels, patches), rtol=0, atol=0)


def test_a_bench_subject_may_time_a_prompt_of_fewer_real_tokens_than_its_padded_length(vlm_directory):
    from snapflow.adapters.lerobot.base import OBS_LANGUAGE_ATTENTION_MASK
    from snapflow.benchmark.subjects import lerobot_subject, with_prompt_tokens

    subject = lerobot_subject(build_tiny_smolvla(vlm_directory), "tiny", torch.device("cpu"), torch.float32)
    full = subject.observation[OBS_LANGUAGE_ATTENTION_MASK]
    assert bool(full.all()), "by default every token is real: the most a prefix costs"
    shorter = with_prompt_tokens(subject, 3)
    assert shorter.observation[OBS_LANGUAGE_ATTENTION_MASK].tolist() == [[True] * 3 + [False] * (full.shape[1] - 3)]
    assert shorter.details["prompt_tokens"] == 3 and "prompt_tokens" not in subject.details
    with pytest.raises(ValueError, match=rf"--prompt-tokens must be in \[1, {full.shape[1]}\]"):
        with_prompt_tokens(subject, full.shape[1] + 1)


@pytest.mark.parametrize("episodes", [None, [0, 2]])
def test_training_frames_are_lerobots_own_delta_timestamp_items(tmp_path, episodes):
    """Each training frame equals what LeRobot's ``delta_timestamps`` gives, key for key and bit for bit (images,
    state, the chunk with its repeated last actions, ``action_is_pad``), on all episodes or some (a held-out one
    left out between them): only the way the chunk is read differs."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    from snapflow.adapters.lerobot.data import ActionChunks
    from tests.lerobot_tiny import write_tiny_dataset

    root = write_tiny_dataset(tmp_path / "dataset", episodes=3, frames=12, fps=10)
    ours = ActionChunks(LeRobotDataset("local/tiny", root=root, episodes=episodes), chunk_size=5)
    chunk = {"action": [step / 10 for step in range(5)]}
    theirs = LeRobotDataset("local/tiny", root=root, episodes=episodes, delta_timestamps=chunk)
    count = len(episodes or range(3))
    assert len(ours) == len(theirs) == 12 * count
    padded = 0
    for position in range(len(theirs)):
        mine, lerobots = ours[position], theirs[position]
        assert mine.keys() == lerobots.keys()
        for key, value in lerobots.items():
            if isinstance(value, torch.Tensor):
                assert mine[key].dtype == value.dtype and torch.equal(mine[key], value), (position, key)
            else:
                assert mine[key] == value, (position, key)
        padded += int(lerobots["action_is_pad"].any())
    assert padded == 4 * count, "each episode's last four frames reach past its end"
