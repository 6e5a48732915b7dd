"""LeRobot's SmolVLAPolicy (lerobot 0.4.4 and newer), PI0Policy and PI05Policy (lerobot >= 0.5), each built offline at
tiny size: what is not the per-adapter contract (tests/adapters/lerobot_contract.py) nor the CLI end to end
(tests/adapters/test_lerobot_cli.py): the registry's refusals, gradient checkpointing, the vision tower's precision."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

pytest.importorskip("lerobot", reason="LeRobot is installed by the README's test command; this environment lacks it")

from packaging.version import Version  # noqa: E402

from snapflow import SnapFlowObjective  # noqa: E402
from snapflow.adapters.lerobot import wrap_policy  # noqa: E402
from snapflow.adapters.lerobot.evaluation import LoadedLeRobotPolicy  # noqa: E402
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

    with pytest.raises(ValueError, match="smolvla, vla_jepa, xvla policies, not 'act': a transformer that regresses"):
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

    with tiny_pi_configs(policy_type):
        model = randomise_target_time(wrap_policy(build_tiny_pi(policy_type)))
    subject = LoadedLeRobotPolicy.of_model(model, Path("<tiny>"), distilled=True).bench_subject("tiny")
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
    from snapflow.benchmark.subjects import with_prompt_tokens

    tiny = LoadedLeRobotPolicy.of_model(build_tiny_smolvla(vlm_directory), Path("<tiny>"), distilled=True)
    subject = tiny.bench_subject("tiny")
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
