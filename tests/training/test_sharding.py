"""A student sharded over the processes of a launch (``snapflow distill --shard``, :mod:`snapflow.training.sharding`):
which modules are gathered one block at a time, what is refused, and a tiny pi0.5 distilled sharded over two CPU
processes (gloo) against one process at the same global batch.

TOLERANCE bounds the largest difference of a weight (and of an optimizer moment) between the sharded run and the one
process, after 2 and 4 steps at a learning rate of 1e-3 without warm-up: a step drawn otherwise (other pairs, noise or
times) moves a weight by about an Adam step, 1e-3, while the sharded run's gathered gradients differ from one
process's by rounding only. Measured: 2.6e-6 (a weight whose gradient is near zero, where Adam divides the rounding
by the gradient's own small scale), the weights having moved 4.0e-3 from the teacher.
"""

from __future__ import annotations

import json

import pytest
import torch
from torch import nn

from snapflow.cli import main
from tests.training.test_data_parallel import (
    TINY_MLP,
    checkpoints,
    history,
    killed,
    largest_difference,
    launched,
    weights,
)

TOLERANCE = 1e-5


class Block(nn.Module):
    def __init__(self) -> None:
        super().__init__()
        self.parts = nn.ModuleList([nn.Linear(8, 8), nn.Linear(8, 8)])


class Tower(nn.Module):
    """An embedding table (8000 weights), three blocks of two linear layers (144 each, 72 a part), a norm, an output
    head (9000) and a small projection."""

    def __init__(self) -> None:
        super().__init__()
        self.embed = nn.Embedding(1000, 8)
        self.blocks = nn.ModuleList([Block() for _ in range(3)])
        self.norm = nn.LayerNorm(8)
        self.head = nn.Linear(8, 1000, bias=False)
        self.projection = nn.Linear(8, 2)


def test_the_blocks_and_the_leaves_larger_than_a_block_are_the_units_gathered_one_at_a_time():
    from snapflow.training.sharding import shard_units

    tower = Tower()
    units = shard_units(tower)
    parts = [part for block in tower.blocks for part in block.parts]
    expected = {id(module) for module in [*tower.blocks, *parts, tower.embed, tower.head]}
    assert {id(unit) for unit in units} == expected and len(units) == len(expected), "not the norm, not the projection"
    for position, unit in enumerate(units):  # fully_shard meets every module after its descendants
        inner = {id(module) for module in unit.modules() if module is not unit}
        assert not inner & {id(later) for later in units[position + 1 :]}
    tower.head.weight = tower.embed.weight  # tied: one weight, which two units cannot both hold
    assert {id(unit) for unit in shard_units(tower)} == {id(module) for module in [*tower.blocks, *parts]}


def test_what_sharding_cannot_run_is_refused_in_one_line(monkeypatch):
    from snapflow.errors import InvalidInputError
    from snapflow.objective.consistency_distillation import ConsistencyDistillationObjective
    from snapflow.objective.snapflow import SnapFlowObjective
    from snapflow.training.config import TrainConfig
    from snapflow.training.sharding import check_sharding, refuse_accelerate_fsdp

    config, objective = TrainConfig(), SnapFlowObjective()
    check_sharding(2, config, objective)
    refusals = {
        "this is one process": (1, config, objective),
        "--ema-decay is not supported with --shard": (2, TrainConfig(ema_decay=0.9), objective),
        "ConsistencyDistillationObjective keeps a moving-average copy": (2, config, ConsistencyDistillationObjective()),
        "not fp16": (2, TrainConfig(mixed_precision="fp16"), objective),
    }
    for message, arguments in refusals.items():
        with pytest.raises(InvalidInputError, match=message):
            check_sharding(*arguments)
    refuse_accelerate_fsdp()
    monkeypatch.setenv("ACCELERATE_USE_FSDP", "true")  # what accelerate launch --use_fsdp sets
    with pytest.raises(InvalidInputError, match="does not run under Accelerate's own FSDP"):
        refuse_accelerate_fsdp()


def test_the_command_refuses_a_sharded_student_on_one_process_and_under_accelerates_fsdp(tmp_path, monkeypatch, capsys):
    from tests.training.fixtures import synthetic_demonstrations

    demonstrations = synthetic_demonstrations(episodes_per_task=2).save(tmp_path / "demos")
    teacher = ["train", *TINY_MLP, "--data", str(demonstrations), "--steps", "1", "--batch-size", "4"]
    assert main([*teacher, "--output", str(tmp_path / "teacher"), "--no-progress"]) == 0
    distill = ["distill", "--teacher", str(tmp_path / "teacher"), "--data", str(demonstrations), "--steps", "1"]
    distill += ["--batch-size", "4", "--output", str(tmp_path / "student"), "--shard", "--no-progress"]
    capsys.readouterr()
    assert main(distill) == 2
    assert (
        "--shard splits the student over the processes of a launch, and this is one process" in capsys.readouterr().err
    )
    monkeypatch.setenv("ACCELERATE_USE_FSDP", "true")
    assert main([argument for argument in distill if argument != "--shard"]) == 2
    assert "launch with --multi_gpu --num_processes N and give snapflow distill --shard" in capsys.readouterr().err
    assert not (tmp_path / "student").exists(), "refused before the run folder is made"


def skip_without_pi05() -> None:
    pytest.importorskip("lerobot", reason="LeRobot is installed by the README's test command")
    from tests.lerobot_tiny import PI_SKIP

    if PI_SKIP.args[0]:
        pytest.skip(PI_SKIP.kwargs["reason"])


@pytest.fixture(scope="module")
def tiny_pi05(tmp_path_factory):
    """A tiny pi0.5 teacher folder and a LeRobotDataset of 2 episodes of 8 frames (PaliGemma's tokenizer: the tiny
    one)."""
    skip_without_pi05()
    from tests.lerobot_tiny import build_tiny_pi, cache_as_hub_repo, write_tiny_dataset, write_tiny_smolvlm

    folder = tmp_path_factory.mktemp("tiny_pi05")
    cache_as_hub_repo(write_tiny_smolvlm(folder / "smolvlm"), "google/paligemma-3b-pt-224")
    build_tiny_pi("pi05").save_pretrained(folder / "teacher")
    return folder / "teacher", write_tiny_dataset(folder / "dataset", episodes=2, frames=8)


@pytest.mark.lerobot
def test_the_frozen_vlm_and_the_expert_of_pi05_are_sharded_block_by_block():
    skip_without_pi05()
    from snapflow.adapters.lerobot import wrap_policy
    from snapflow.training.sharding import shard_units
    from tests.lerobot_tiny import build_tiny_pi

    adapter = wrap_policy(build_tiny_pi("pi05"))
    paligemma = adapter.policy.model.paligemma_with_expert.paligemma
    expert = adapter.policy.model.paligemma_with_expert.gemma_expert
    expected = [
        *paligemma.model.vision_tower.vision_model.encoder.layers,
        *paligemma.model.language_model.layers,
        paligemma.model.language_model.embed_tokens,
        paligemma.lm_head,
        *expert.model.layers,
        expert.lm_head,
    ]
    assert {id(unit) for unit in shard_units(adapter)} == {id(module) for module in expected}


@pytest.mark.slow
@pytest.mark.lerobot
def test_a_pi05_student_sharded_over_two_processes_trains_as_one_process_resumes_and_opens_whole(tiny_pi05, tmp_path):
    """``snapflow distill --shard`` of the tiny pi0.5 on two CPU processes, killed after step 2 of 4 and launched
    again with ``--resume``, against one process at the global batch 4: every checkpoint's weights and optimizer
    state within TOLERANCE, the same loss history; only the main process writes; the exported policy opens in
    ``open_policy`` on this one process, its VLM the teacher's bit for bit, its expert and phi_s trained."""
    from safetensors.torch import load_file

    from snapflow.sources import open_policy
    from tests.lerobot_tiny import tiny_pi_configs

    teacher, dataset = tiny_pi05
    common = ["distill", "--policy", str(teacher), "--dataset", str(dataset), "--repo-id", "local/tiny"]
    common += ["--steps", "4", "--batch-size", "4", "--learning-rate", "1e-3", "--warmup-steps", "1"]
    common += ["--checkpoint-every", "2", "--no-progress"]
    alone, pair = tmp_path / "one", tmp_path / "two"
    with tiny_pi_configs("pi05"):
        assert main([*common, "--output", str(alone)]) == 0
    sharded = [*common, "--output", str(pair), "--shard"]
    killed(tmp_path / "killed", pair, "snapflow", sharded, step=2, probe="tiny-pi05")
    assert json.loads((pair / "latest.json").read_text()) == {"checkpoint": "checkpoints/step_0000002"}
    finished = launched(tmp_path / "again", pair, "snapflow", [*sharded, "--resume"], probe="tiny-pi05")
    assert finished.stdout.count(f"resuming {pair} at step 2") == 1

    assert [path.name for path in checkpoints(pair)] == ["step_0000002", "step_0000004"]
    for one, two in zip(checkpoints(alone), checkpoints(pair), strict=True):
        for name in ("policy.safetensors", "optimizer.safetensors"):
            assert largest_difference(weights(one, name), weights(two, name)) < TOLERANCE, (one.name, name)
    for one, two in zip(history(alone)["history"], history(pair)["history"], strict=True):
        assert two["step"] == one["step"] and two["loss"] == pytest.approx(one["loss"], rel=1e-5)

    with tiny_pi_configs("pi05"):
        opened = open_policy(pair / "lerobot_policy")
    assert opened.distilled
    exported = {name: tensor.detach() for name, tensor in opened.policy.policy.state_dict().items()}
    alone_export = load_file(alone / "lerobot_policy" / "model.safetensors")
    assert largest_difference(alone_export, exported) < TOLERANCE
    start = load_file(teacher / "model.safetensors")
    vlm = [name for name in start if ".paligemma." in name]
    assert vlm and all(torch.equal(exported[name], start[name]) for name in vlm), "the frozen VLM, gathered whole"
    expert = [name for name in start if ".gemma_expert." in name]
    assert max((exported[name] - start[name]).abs().max().item() for name in expert) > 1e-3, "the expert trained"
    assert exported["model.target_time_embedding.linear_out.weight"].abs().sum() > 0, "phi_s trained"
