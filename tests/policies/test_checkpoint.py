"""A built-in policy on disk: write_policy / load_policy give back every bit, for both policies."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from snapflow.nn import SnapFlowPolicy
from snapflow.policies.checkpoint import (
    LATEST,
    POLICY_CONFIG,
    POLICY_WEIGHTS,
    CheckpointError,
    load_policy,
    load_state_strict,
    policy_metadata,
    read_tensors,
    resolve_checkpoint,
    write_policy,
)
from snapflow.policies.configuration import PolicyConfig
from snapflow.policies.factory import make_model, make_processor
from snapflow.policies.minivla import MiniVLAConfig
from snapflow.policies.mlp import MLPPolicyConfig
from snapflow.policies.normalization import NormalizationStats
from snapflow.policies.processor import Processor
from tests.helpers import randomise_target_time

INSTRUCTIONS = ["reach the goal", "push the puck"]
CONFIGS: dict[str, PolicyConfig] = {
    "mlp": MLPPolicyConfig(
        observation_dim=5 + len(INSTRUCTIONS), action_dim=2, chunk_length=3, hidden_dim=16, time_embedding_dim=8
    ),
    "minivla": MiniVLAConfig(
        state_dim=5,
        action_dim=2,
        chunk_length=3,
        use_image=True,
        image_size=16,
        patch_size=8,
        prefix_width=16,
        expert_width=16,
        num_layers=1,
        num_heads=2,
        head_dim=8,
    ),
}
STATS = NormalizationStats([0.1, 0.2, 0.3, 0.4, 0.5], [1.0, 2.0, 3.0, 4.0, 5.0], [-0.5, 0.5], [0.25, 4.0])


def _save(directory: Path, name: str, target_time: bool) -> tuple[SnapFlowPolicy, Processor]:
    """A policy with every tensor random (phi_s too, when attached), written to ``directory``."""
    torch.manual_seed(0)
    policy = SnapFlowPolicy(make_model(CONFIGS[name]), target_time=target_time)
    with torch.no_grad():
        for parameter in policy.model.parameters():
            parameter.add_(0.1 * torch.randn_like(parameter))  # zero-initialised layers too
    if target_time:
        randomise_target_time(policy)
    processor = make_processor(CONFIGS[name], STATS, INSTRUCTIONS)
    directory.mkdir(parents=True, exist_ok=True)
    write_policy(directory, policy, policy_metadata(policy, processor, stage="test"))
    return policy, processor


def _velocity(policy: SnapFlowPolicy, processor: Processor) -> torch.Tensor:
    generator = torch.Generator().manual_seed(1)
    states = torch.randn(2, 5, generator=generator).numpy()
    images = np.random.default_rng(1).integers(0, 256, size=(2, 16, 16, 3), dtype=np.uint8)
    context = policy.encode(processor.observation(states, INSTRUCTIONS, images))
    x, t = torch.randn(2, 3, 2, generator=generator), torch.tensor([1.0, 0.5])
    return policy.velocity(x, t, torch.zeros(2), context)


@pytest.mark.parametrize("name", list(CONFIGS))
@pytest.mark.parametrize("target_time", [True, False])
def test_round_trip_is_bit_identical(tmp_path: Path, name: str, target_time: bool):
    """Every tensor, the configuration, the processor's statistics and instructions, and so every velocity, come
    back bit for bit; the metadata names the registered policy."""
    saved, processor = _save(tmp_path, name, target_time)
    loaded = load_policy(tmp_path)
    assert loaded.path == tmp_path and loaded.metadata["policy"] == name and loaded.metadata["stage"] == "test"
    assert (loaded.policy.target_time_embedding is not None) == target_time
    expected, actual = saved.state_dict(), loaded.policy.state_dict()
    assert list(actual) == list(expected)
    for key, tensor in expected.items():
        assert actual[key].dtype == tensor.dtype and torch.equal(actual[key], tensor), key
    assert type(loaded.processor) is type(processor) and loaded.processor.config == CONFIGS[name]
    assert loaded.processor.stats == STATS and loaded.processor.instructions == tuple(INSTRUCTIONS)
    assert torch.equal(_velocity(loaded.policy, loaded.processor), _velocity(saved, processor))


@pytest.mark.parametrize("name", list(CONFIGS))
def test_a_teacher_loads_as_a_student_but_a_student_not_as_a_teacher(tmp_path: Path, name: str):
    """Distillation starts from a teacher with a fresh, zero phi_s (so the same velocities); a student's phi_s cannot
    be dropped on loading."""
    teacher, processor = _save(tmp_path / "teacher", name, target_time=False)
    student = load_policy(tmp_path / "teacher", target_time=True).policy
    assert torch.count_nonzero(student.target_time_embedding.linear_out.weight) == 0
    assert torch.equal(_velocity(student, processor), _velocity(teacher, processor))
    _save(tmp_path / "student", name, target_time=True)
    with pytest.raises(CheckpointError, match="is a SnapFlow student; it cannot be loaded without its target-time"):
        load_policy(tmp_path / "student", target_time=False)


def test_a_run_folder_resolves_to_the_checkpoint_its_latest_json_names(tmp_path: Path):
    """A run directory is read through latest.json; a folder that is neither is named."""
    checkpoint = tmp_path / "checkpoints" / "step_0000002"
    _save(checkpoint, "mlp", target_time=True)
    (tmp_path / LATEST).write_text(json.dumps({"checkpoint": "checkpoints/step_0000002"}))
    assert resolve_checkpoint(tmp_path) == checkpoint and resolve_checkpoint(checkpoint) == checkpoint
    assert load_policy(tmp_path).path == checkpoint
    (checkpoint / POLICY_CONFIG).unlink()
    with pytest.raises(CheckpointError, match="holds neither a checkpoint"):
        load_policy(checkpoint)


def test_a_tensor_tied_under_two_names_is_saved_once_and_loaded_under_both(tmp_path: Path):
    """A shared embedding (Florence-2's in X-VLA) is one tensor under two names: safetensors refuses it twice, so it
    is saved under its first name and read back into both."""
    from torch import nn

    def tied() -> nn.Module:
        module = nn.ModuleDict({"shared": nn.Embedding(5, 3), "encoder": nn.ModuleDict({"tokens": nn.Embedding(5, 3)})})
        module["encoder"]["tokens"].weight = module["shared"].weight
        return module

    saved = tied()
    write_policy(tmp_path, saved, {})
    assert set(read_tensors(tmp_path / POLICY_WEIGHTS)) == {"shared.weight"}
    loaded = tied()
    load_state_strict(loaded, read_tensors(tmp_path / POLICY_WEIGHTS), tmp_path / POLICY_WEIGHTS)
    assert torch.equal(loaded["shared"].weight, saved["shared"].weight)
    assert loaded["encoder"]["tokens"].weight is loaded["shared"].weight, "still one tensor"
    with pytest.raises(CheckpointError, match=r"missing \['shared.weight'\]"):  # an untied module needs both
        load_state_strict(
            nn.ModuleDict({"shared": nn.Embedding(5, 3)}), {"other.weight": torch.zeros(5, 3)}, tmp_path / "x"
        )
