"""The adapter contract run by every LeRobot policy type snapflow distils: SmolVLA, pi0, pi0.5, X-VLA and
multi-task DiT here, GR00T N1.7, EVO1 and VLA-JEPA in ``test_contract_<type>.py``; a declared type without a class
fails :func:`test_every_lerobot_adapter_runs_the_contract`."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
import torch
from packaging.version import Version
from torch import Tensor, nn

from snapflow import NAIVE_1, sample_actions
from tests.adapters.contract import TEACHER_10, contract_classes
from tests.adapters.lerobot_contract import LeRobotAdapterContract
from tests.lerobot_tiny import PI_SKIP, TRANSFORMERS, randomise_target_time


class TestSmolVLAAdapter(LeRobotAdapterContract):
    policy_type = "smolvla"
    compile_backend = "inductor"  # the one LeRobot type whose compiled numerics are checked (inductor, C++ kernels)
    capabilities = frozenset({"HostSyncFree"})
    # before transformers 5, SmolVLM sizes its patches' position ids by .item(), once per image: each breaks the graph
    deploy_graphs = 1 if TRANSFORMERS and TRANSFORMERS >= Version("5") else None


@PI_SKIP
class TestPI0Adapter(LeRobotAdapterContract):
    policy_type = "pi0"
    capabilities = frozenset({"VisionPrecision"})


@PI_SKIP
class TestPI05Adapter(LeRobotAdapterContract):
    policy_type = "pi05"
    capabilities = frozenset({"VisionPrecision"})  # pi0's adapter's, inherited


@PI_SKIP
class TestXVLAAdapter(LeRobotAdapterContract):
    """X-VLA predicts the clean chunk: LeRobot has no velocity of it, so its "own" velocity is written out here by
    hand from LeRobot's transformer, v = (x_t - a_hat) / t, and Euler-integrated on snapflow's grid."""

    policy_type = "xvla"
    deploy_graphs = None  # Florence-2's encoder counts the valid views by .item(): its graph breaks there

    def build_lerobot(self) -> nn.Module:
        from tests.lerobot_tiny_xvla import build_tiny_xvla

        return build_tiny_xvla()

    def load(self, directory: Path) -> nn.Module:
        from tests.lerobot_tiny_xvla import without_dropout

        return without_dropout(super().load(directory))

    @staticmethod
    def own_velocity(lerobot: nn.Module, encoded: dict, inputs: dict, x: Tensor, t: Tensor) -> Tensor:
        proprio, noisy = lerobot.model.action_space.preprocess(inputs["proprio"], x)
        clean = lerobot.model.transformer(
            domain_id=inputs["domain_id"], action_with_noise=noisy, proprio=proprio, t=t, **encoded
        )
        return (x - clean) / t[:, None, None]

    def lerobot_own_sample(self, lerobot: nn.Module, observation: Any, noise: Tensor, steps: int) -> Tensor:
        inputs = lerobot._build_model_inputs(observation)
        grid = torch.linspace(1.0, 0.0, steps + 1)
        with torch.no_grad():
            encoded = lerobot.model.forward_vlm(inputs["input_ids"], inputs["image_input"], inputs["image_mask"])
            x = noise
            for t, t_next in zip(grid[:-1], grid[1:], strict=True):
                velocity = self.own_velocity(lerobot, encoded, inputs, x, t.expand(noise.shape[0]))
                x = x + (t_next - t).expand(noise.shape[0])[:, None, None] * velocity
        return x

    def lerobot_own_flow_matching_loss(
        self, lerobot: nn.Module, observation: Any, actions: Tensor, noise: Tensor, time: Tensor
    ) -> Tensor:
        inputs = lerobot._build_model_inputs(observation)
        encoded = lerobot.model.forward_vlm(inputs["input_ids"], inputs["image_input"], inputs["image_mask"])
        x_t = time[:, None, None] * noise + (1 - time[:, None, None]) * actions
        return (self.own_velocity(lerobot, encoded, inputs, x_t, time) - (noise - actions)).pow(2).mean()

    def lerobot_chunk(self, lerobot: nn.Module, observation: Any, noise: Tensor) -> Tensor:
        # X-VLA's action API takes no noise: it draws its own after the prefix, from the global generator
        torch.manual_seed(0)
        return lerobot.predict_action_chunk(observation)

    def test_xvlas_own_one_step_sampler_is_the_naive_step(self, policy, batch):
        """X-VLA's own sampler at one step returns its clean prediction at t = 1: the naive step's x_1 - v."""
        randomise_target_time(policy)
        observation, actions = batch
        inputs = policy.policy._build_model_inputs(observation)
        torch.manual_seed(0)
        with torch.no_grad():
            own = policy.policy.model.generate_actions(**inputs, steps=1)
        naive = sample_actions(policy, observation, self.noise_like(actions), NAIVE_1)
        torch.testing.assert_close(own, naive, atol=1e-6, rtol=0)


@PI_SKIP
class TestMultiTaskDiTAdapter(LeRobotAdapterContract):
    """Multi-task DiT by flow matching runs its flow the other way (t = 0 noise): its "own" Euler is written out
    here by hand from LeRobot's transformer, on snapflow's grid, its velocity negated at LeRobot's time 1 - t."""

    policy_type = "multi_task_dit"
    deploy_graphs = None  # torchvision's crop and CLIP's pooling by token id split the prefix's graph

    @pytest.fixture(autouse=True)
    def _tiny_clip(self, clip_directory: Path) -> None:
        self.clip_directory = clip_directory

    def build_lerobot(self) -> nn.Module:
        from tests.lerobot_tiny_multi_task_dit import build_tiny_multi_task_dit

        return build_tiny_multi_task_dit(self.clip_directory)

    @staticmethod
    def encoded(lerobot: nn.Module, observation: Any) -> Tensor:
        from snapflow.adapters.lerobot.base import frozen_prefix_pass
        from tests.lerobot_tiny import model_inputs

        (batch,) = model_inputs(lerobot, observation)
        with frozen_prefix_pass(lerobot.observation_encoder):  # eval mode: the centre crop
            return lerobot.observation_encoder.encode(batch)

    @staticmethod
    def own_velocity(lerobot: nn.Module, conditioning: Tensor, x: Tensor, t: Tensor) -> Tensor:
        return -lerobot.noise_predictor(x, 1 - t, conditioning_vec=conditioning)

    def lerobot_own_sample(self, lerobot: nn.Module, observation: Any, noise: Tensor, steps: int) -> Tensor:
        grid = torch.linspace(1.0, 0.0, steps + 1)
        with torch.no_grad():
            conditioning, x = self.encoded(lerobot, observation), noise
            for t, t_next in zip(grid[:-1], grid[1:], strict=True):
                velocity = self.own_velocity(lerobot, conditioning, x, t.expand(noise.shape[0]))
                x = x + (t_next - t).expand(noise.shape[0])[:, None, None] * velocity
        return x

    def lerobot_own_flow_matching_loss(
        self, lerobot: nn.Module, observation: Any, actions: Tensor, noise: Tensor, time: Tensor
    ) -> Tensor:
        x_t = time[:, None, None] * noise + (1 - time[:, None, None]) * actions
        velocity = self.own_velocity(lerobot, self.encoded(lerobot, observation), x_t, time)
        return (velocity - (noise - actions)).pow(2).mean()

    def lerobot_chunk(self, lerobot: nn.Module, observation: Any, noise: Tensor) -> Tensor:
        from lerobot.policies.utils import populate_queues

        # its action API reads the observation queues select_action fills, and draws its own noise after the prefix
        lerobot.reset()
        batch = lerobot._prepare_batch({key: value for key, value in observation.items() if key != "action"})
        lerobot._queues = populate_queues(lerobot._queues, batch)
        torch.manual_seed(0)
        return lerobot.predict_action_chunk(batch)

    def test_its_own_ten_euler_steps_are_the_teacher_mode_within_rounding(self, policy, batch):
        """LeRobot's own integrator (100 steps by default, 10 in the tiny config) runs the same flow as
        ``teacher-10``, on its own time grid."""
        observation, actions = batch
        lerobot = policy.policy
        with torch.no_grad():
            conditioning = self.encoded(lerobot, observation)
            torch.manual_seed(0)
            own = lerobot.objective.conditional_sample(lerobot.noise_predictor, self.batch_size, conditioning)
        teacher = sample_actions(policy, observation, self.noise_like(actions), TEACHER_10)
        torch.testing.assert_close(own, teacher, atol=1e-5, rtol=1e-5)

    def test_a_ddpm_trained_policy_is_refused_by_name(self):
        from lerobot.policies.multi_task_dit.modeling_multi_task_dit import MultiTaskDiTPolicy

        from snapflow.adapters.lerobot import wrap_policy
        from snapflow.errors import InvalidInputError

        config = self.build_lerobot().config
        config.objective = "diffusion"
        with pytest.raises(InvalidInputError, match="a DDPM denoiser has no velocity field"):
            wrap_policy(MultiTaskDiTPolicy(config))


def test_every_lerobot_adapter_runs_the_contract():
    import tests.adapters.test_contract_eo1  # noqa: F401  (their classes, however this module was collected)
    import tests.adapters.test_contract_evo1  # noqa: F401
    import tests.adapters.test_contract_groot  # noqa: F401
    import tests.adapters.test_contract_molmoact2  # noqa: F401
    import tests.adapters.test_contract_vla_jepa  # noqa: F401
    from snapflow.adapters.lerobot_types import LEROBOT_POLICY_TYPES

    assert sorted(cls.policy_type for cls in contract_classes(LeRobotAdapterContract)) == sorted(LEROBOT_POLICY_TYPES)
