"""The adapter contract on LeRobot's GR00T N1.7 (lerobot >= 0.6), built offline at tiny size
(tests/lerobot_tiny_groot.py)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
import torch
from torch import Tensor, nn

from snapflow import SamplingMode, sample_actions
from tests.adapters.lerobot_contract import LeRobotAdapterContract


class TestGrootAdapter(LeRobotAdapterContract):
    """GR00T N1.7 runs its flow the other way (t = 0 noise) on whole time buckets: its "own" Euler and training
    forward are written out here by hand from LeRobot's action head, as its ``get_action_with_features`` and
    ``forward`` run them (its own grid and update), on its own prefix (``_encode_features``)."""

    policy_type = "groot"
    deploy_graphs = None  # Qwen3-VL reads its image grid and rotary positions on the host (.item(), nonzero)

    @pytest.fixture(autouse=True)
    def _tiny_groot(self, groot_checkpoint: Path) -> None:
        self.groot_checkpoint = groot_checkpoint

    def build_lerobot(self) -> nn.Module:
        from tests.lerobot_tiny_groot import build_tiny_groot

        return build_tiny_groot(self.groot_checkpoint)

    def observations(self, batch_size: int) -> dict[str, Any]:
        from tests.lerobot_tiny_groot import raw_groot_batch, tiny_groot_processors

        preprocessor, _ = tiny_groot_processors(self.build_lerobot())
        return preprocessor(raw_groot_batch(batch_size))

    @staticmethod
    def rows(observation: dict[str, Any], rows: slice) -> dict[str, Any]:
        from tests.lerobot_tiny_groot import groot_rows

        return groot_rows(observation, rows)

    @staticmethod
    def own_prefix(lerobot: nn.Module, observation: Any) -> dict[str, Tensor]:
        from transformers.feature_extraction_utils import BatchFeature

        from snapflow.adapters.lerobot.base import frozen_prefix_pass
        from tests.lerobot_tiny import model_inputs

        backbone_inputs, action_inputs = (BatchFeature(part) for part in model_inputs(lerobot, observation))
        with frozen_prefix_pass(lerobot._groot_model):
            backbone = lerobot._groot_model.backbone(backbone_inputs)
            features = lerobot._groot_model.action_head._encode_features(backbone, action_inputs)
        return {**backbone, **features, "embodiment_id": action_inputs["embodiment_id"]}

    @staticmethod
    def own_prediction(lerobot: nn.Module, prefix: dict[str, Tensor], x: Tensor, bucket: Tensor) -> Tensor:
        """GR00T's loop body: its velocity (data - noise) at its time bucket."""
        head, embodiment = lerobot._groot_model.action_head, prefix["embodiment_id"]
        features = head.action_encoder(x, bucket, embodiment) + head.position_embedding(torch.arange(x.shape[1]))
        output = head.model(
            hidden_states=torch.cat((prefix["state_features"], features), dim=1),
            encoder_hidden_states=prefix["backbone_features"],
            timestep=bucket,
            image_mask=prefix["image_mask"],
            backbone_attention_mask=prefix["backbone_attention_mask"],
        )
        return head.action_decoder(output, embodiment)[:, -x.shape[1] :]

    def lerobot_own_sample(self, lerobot: nn.Module, observation: Any, noise: Tensor, steps: int) -> Tensor:
        with torch.no_grad():
            prefix, x = self.own_prefix(lerobot, observation), noise
            for step in range(steps):  # GR00T's grid (t = step / steps, bucketed) and update
                bucket = torch.full((noise.shape[0],), int(step / steps * 1000))
                x = x + 1.0 / steps * self.own_prediction(lerobot, prefix, x, bucket)
        return x

    def lerobot_own_flow_matching_loss(
        self, lerobot: nn.Module, observation: Any, actions: Tensor, noise: Tensor, time: Tensor
    ) -> Tensor:
        own_time = (1 - time)[:, None, None]  # GR00T's path and bucket; its squared error over the masked entries
        x_t = (1 - own_time) * noise + own_time * actions
        bucket = (own_time[:, 0, 0] * 1000).long()
        prediction = self.own_prediction(lerobot, self.own_prefix(lerobot, observation), x_t, bucket)
        mask = observation["action_mask"]
        return ((prediction - (actions - noise)).pow(2) * mask).sum() / (mask.sum() + 1e-6)

    def entry_weights(self, observation: Any, actions: Tensor) -> Tensor:
        """GR00T's ``action_mask``: its padded width (and steps past an episode's end) weigh nothing."""
        mask = observation["action_mask"].expand_as(actions)
        assert 0 < mask.sum() < mask.numel(), "the tiny GR00T's chunks hold padding"
        return mask

    def lerobot_chunk(self, lerobot: nn.Module, observation: Any, noise: Tensor) -> Tensor:
        """The padded chunk GR00T's action API samples (it draws its own noise after the prefix), checked against the
        one it returns, cut to the real horizon and action width."""
        head, sampled = lerobot._groot_model.action_head, []
        get_action = head.get_action
        head.get_action = lambda *inputs, **options: sampled.append(get_action(*inputs, **options)) or sampled[-1]
        torch.manual_seed(0)
        try:
            chunk = lerobot.predict_action_chunk(observation)
        finally:
            head.get_action = get_action
        (padded,) = (output["action_pred"] for output in sampled)
        assert torch.equal(chunk, padded[:, : chunk.shape[1], : chunk.shape[2]]) and chunk.shape[2] < padded.shape[2]
        return padded

    def test_its_own_four_step_sampler_is_the_teacher_mode_bit_for_bit(self, policy, batch):
        """GR00T's own ``get_action_with_features`` (4 steps, int buckets, its noise drawn after the prefix) is
        ``teacher-4`` on snapflow's grid, at the policy's own steps."""
        from transformers.feature_extraction_utils import BatchFeature

        observation, actions = batch
        lerobot = policy.policy
        assert type(policy).own_steps(lerobot.config) == 4
        head = lerobot._groot_model.action_head
        prefix = self.own_prefix(lerobot, observation)
        torch.manual_seed(0)
        own = type(head).get_action_with_features(
            head,
            prefix["backbone_features"],
            prefix["state_features"],
            prefix["embodiment_id"],
            BatchFeature(prefix),
            BatchFeature({}),
        )["action_pred"]
        assert torch.equal(own, sample_actions(policy, observation, self.noise_like(actions), SamplingMode(4, False)))

    def test_its_training_times_are_pi0s_beta_in_snapflows_direction(self, policy):
        from snapflow.flow.time_sampling import BetaTimeSampler

        assert type(policy).training_time_sampler(policy.policy.config) == BetaTimeSampler(1.5, 0.001)

    def test_a_config_padding_to_other_widths_than_its_checkpoint_is_refused_by_name(self):
        """GR00T builds its encoders from the checkpoint, its pre-processor pads to the config's widths: where the two
        differ, GR00T itself fails deep in its state encoder; the adapter names both."""
        from lerobot.policies.groot.modeling_groot import GrootPolicy

        from snapflow.adapters.lerobot import wrap_policy
        from snapflow.errors import InvalidInputError

        config = self.build_lerobot().config
        config.max_state_dim = 132
        with pytest.raises(InvalidInputError, match="pads to max_state_dim=132, but its checkpoint .* built for 8"):
            wrap_policy(GrootPolicy(config))


def test_the_checkpoint_writer_runs_as_a_module_and_its_checkpoint_builds_a_groot(groot_checkpoint, tmp_path):
    """``python -m snapflow.adapters.lerobot.groot_checkpoint DIR --size tiny``, as the LeRobot guide gives it for a
    full-size one: its folder is what LeRobot's GrootPolicy builds from, and the same seed writes the same weights."""
    import subprocess
    import sys

    from safetensors.torch import load_file

    from tests.lerobot_tiny_groot import build_tiny_groot

    command = [sys.executable, "-m", "snapflow.adapters.lerobot.groot_checkpoint", str(tmp_path), "--size", "tiny"]
    written = Path(subprocess.run(command, check=True, capture_output=True, text=True).stdout.strip())
    assert written == tmp_path / "gr00t_n1_7" and (tmp_path / "qwen3_vl" / "config.json").is_file()
    assert build_tiny_groot(written).config.base_model_path == str(written)
    ours, fixture = (load_file(folder / "model.safetensors") for folder in (written, groot_checkpoint))
    assert ours.keys() == fixture.keys() and all(torch.equal(ours[name], fixture[name]) for name in ours)


def test_a_groot_base_checkpoint_given_as_a_policy_is_refused_with_the_step_that_makes_one(
    groot_checkpoint, tmp_path, capsys
):
    """NVIDIA's format holds no LeRobot type and no robot's features: distilling it names LeRobot's fine-tuning over
    it, where LeRobot's loader raised "Missing 'type' field" and snapflow called that a bug of its own."""
    from snapflow.cli import main

    arguments = ["distill", "--policy", str(groot_checkpoint), "--lerobot-train", "--output", str(tmp_path / "out")]
    assert main(arguments) == 2
    error = capsys.readouterr().err
    assert "is a GR00T N1.7 base checkpoint (NVIDIA's format), not a LeRobot policy" in error
    assert f"--policy.base_model_path={groot_checkpoint.resolve()}" in error and "Traceback" not in error
