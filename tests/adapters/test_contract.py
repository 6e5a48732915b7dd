"""The contract (:class:`tests.adapters.contract.FlowPolicyContract`) run by every built-in policy (MiniVLA, MLP),
through :class:`BuiltinPolicyContract`; the LeRobot adapters run it in ``test_contract_lerobot.py`` and
``test_contract_groot.py``. A new built-in policy without a class here fails
:func:`test_every_built_in_policy_runs_the_contract`."""

from __future__ import annotations

from pathlib import Path
from typing import Any, ClassVar

import numpy as np
import pytest
import torch
from torch import Tensor, nn

from snapflow import SamplingMode, SnapFlowPolicy, sample_actions
from snapflow.policies.checkpoint import load_policy, policy_metadata, write_policy
from snapflow.policies.factory import POLICIES, default_config, make_model, make_processor
from snapflow.policies.normalization import NormalizationStats
from tests.adapters.contract import FlowPolicyContract, contract_classes

# ---- the built-in policies ------------------------------------------------------------------------------------

STATE_DIM, ACTION_DIM = 39, 4  # Meta-World's
INSTRUCTIONS = ("push the puck to the goal", "open the drawer", "close the window")


class BuiltinPolicyContract(FlowPolicyContract):
    """A registered built-in policy (``snapflow.policies.factory.POLICIES[name]``) at a tiny size, with its processor
    (unit normalisation) making the observations, under :class:`snapflow.SnapFlowPolicy`."""

    name: ClassVar[str]
    sizes: ClassVar[dict[str, Any]]

    @pytest.fixture(autouse=True)
    def _configure(self) -> None:
        self.config = default_config(self.name, STATE_DIM, ACTION_DIM, INSTRUCTIONS, **self.sizes)
        state_entries = POLICIES[self.name].processor_class.state_entries(self.config, INSTRUCTIONS)
        stats = NormalizationStats([0.0] * state_entries, [1.0] * state_entries, [0.0] * ACTION_DIM, [1.0] * ACTION_DIM)
        self.processor = make_processor(self.config, stats, INSTRUCTIONS)

    def build(self, target_time: bool = True) -> SnapFlowPolicy:
        torch.manual_seed(0)
        return SnapFlowPolicy(self.stand_in_for_trained(make_model(self.config)), target_time=target_time)

    def stand_in_for_trained(self, model: nn.Module) -> nn.Module:
        """Make a random model's output depend on every input, as a trained one's does (default: it already does)."""
        return model

    def reference_sample(self, observation: Any, noise: Tensor, steps: int) -> Tensor:
        return sample_actions(self.build(target_time=False), observation, noise, SamplingMode(steps, jump=False))

    def make_batch(self, policy: nn.Module) -> tuple[Any, Tensor]:
        generator = np.random.default_rng(0)
        images = (
            generator.integers(
                0, 256, (self.batch_size, self.processor.image_size, self.processor.image_size, 3), dtype=np.uint8
            )
            if self.processor.image_size
            else None
        )
        states = generator.standard_normal((self.batch_size, STATE_DIM)).astype(np.float32)
        observation = self.processor.observation(
            states, [INSTRUCTIONS[row % len(INSTRUCTIONS)] for row in range(self.batch_size)], images
        )
        actions = torch.randn(
            self.batch_size,
            self.processor.chunk_length,
            self.processor.action_dim,
            generator=torch.Generator().manual_seed(2),
        )
        return observation, actions

    def save(self, policy: nn.Module, directory: Path) -> None:
        directory.mkdir()
        write_policy(directory, policy, policy_metadata(policy, self.processor, stage="snapflow"))

    def load(self, directory: Path) -> nn.Module:
        return load_policy(directory).policy

    def test_checkpoint_names_the_registered_policy_and_rebuilds_its_classes(self, policy, tmp_path):
        self.save(policy, tmp_path / "saved")
        loaded = load_policy(tmp_path / "saved")
        entry = POLICIES[self.name]
        assert loaded.metadata["policy"] == self.name and loaded.metadata["target_time"] is True
        assert type(loaded.policy.model) is entry.model_class and type(loaded.processor) is entry.processor_class
        assert loaded.processor.config == self.config and loaded.processor.instructions == INSTRUCTIONS


class TestMiniVLAPolicy(BuiltinPolicyContract):
    name = "minivla"
    sizes = dict(
        chunk_length=4,
        prefix_width=32,
        expert_width=32,
        num_layers=1,
        num_heads=2,
        head_dim=16,
        use_image=True,
        image_size=32,
        patch_size=16,
    )

    def stand_in_for_trained(self, model: nn.Module) -> nn.Module:
        # MiniVLA starts its expert blocks as the identity (adaRMS scale, shift and gates at zero, as pi0.5's): time and
        # prefix reach the velocity only once those projections have trained
        generator = torch.Generator().manual_seed(3)
        with torch.no_grad():
            for name, parameter in model.named_parameters():
                if "modulation" in name:
                    parameter.copy_(0.3 * torch.randn(parameter.shape, generator=generator))
        return model


class TestMLPPolicy(BuiltinPolicyContract):
    name = "mlp"
    sizes = dict(chunk_length=4, hidden_dim=32, time_embedding_dim=16)


def test_every_built_in_policy_runs_the_contract():
    assert sorted(cls.name for cls in contract_classes(BuiltinPolicyContract)) == sorted(POLICIES)
