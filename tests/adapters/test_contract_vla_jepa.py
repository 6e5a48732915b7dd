"""The adapter contract on LeRobot's VLA-JEPA (lerobot >= 0.6.1), built offline at tiny size, its world model on
(tests/lerobot_tiny_vla_jepa.py)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
import torch
import torch.nn.functional as F  # noqa: N812
from torch import Tensor, nn

from snapflow import SamplingMode, SnapFlowObjective, sample_actions
from tests.adapters.lerobot_contract import LeRobotAdapterContract
from tests.lerobot_tiny_vla_jepa import FRAMES


class TestVLAJEPAAdapter(LeRobotAdapterContract):
    """VLA-JEPA runs its flow the other way (t = 0 noise) on whole buckets of its time: its "own" Euler and training
    loss are written out here by hand from LeRobot's action head (its ``_build_inputs``, its DiT's blocks and output
    modulation, its action decoder), on its own prefix (Qwen3-VL's embodied-action tokens); phi_s(s) is added to the
    DiT's time embedding, as the student's velocity adds it. The tests below check the adapter against LeRobot's own
    ``predict_action`` and ``forward`` themselves."""

    policy_type = "vla_jepa"
    deploy_graphs = None  # VLA-JEPA builds and tokenizes its prompt on the host, inside the prefix

    @pytest.fixture(autouse=True)
    def _tiny_vla_jepa(self, vla_jepa_backbones: tuple[Path, Path]) -> None:
        self.backbones = vla_jepa_backbones

    def build_lerobot(self) -> nn.Module:
        from tests.lerobot_tiny_vla_jepa import build_tiny_vla_jepa

        return build_tiny_vla_jepa(self.backbones)

    def observations(self, batch_size: int, frames: int = 0) -> dict[str, Any]:
        from tests.lerobot_tiny_vla_jepa import raw_vla_jepa_batch, tiny_vla_jepa_processors

        preprocessor, _ = tiny_vla_jepa_processors(self.build_lerobot())
        return preprocessor(raw_vla_jepa_batch(batch_size, frames=frames))

    @staticmethod
    def rows(observation: dict[str, Any], rows: slice) -> dict[str, Any]:
        from tests.lerobot_tiny_vla_jepa import vla_jepa_rows

        return vla_jepa_rows(observation, rows)

    @staticmethod
    def own_prefix(lerobot: nn.Module, observation: Any) -> dict[str, Any]:
        """VLA-JEPA's ``predict_action`` up to its action head: Qwen3-VL's embodied-action tokens, and the state."""
        inputs = lerobot._prepare_model_inputs(observation, training=False)
        with torch.no_grad():
            tokens, _ = lerobot.model._encode_qwen(inputs["images"], inputs["instructions"], need_action_tokens=False)
        return {"tokens": tokens.float(), "state": inputs["state"]}

    @staticmethod
    def own_prediction(
        lerobot: nn.Module, prefix: dict[str, Any], actions: Tensor, bucket: Tensor, s: Tensor
    ) -> Tensor:
        """VLA-JEPA's velocity (data - noise) at its time ``bucket``: its inputs, its DiT written out, its decoder;
        phi_s(s) added to the DiT's time embedding where the policy is wrapped."""
        head = lerobot.model.action_model
        dit = head.model
        hidden = head._build_inputs(prefix["tokens"], actions, prefix["state"], bucket)
        temb = type(dit.timestep_encoder).forward(dit.timestep_encoder, bucket)
        if hasattr(dit, "target_time_embedding"):
            temb = temb + dit.target_time_embedding(s)
        for block in dit.transformer_blocks:
            hidden = block(hidden, encoder_hidden_states=prefix["tokens"], temb=temb)
        shift, scale = dit.proj_out_1(F.silu(temb)).chunk(2, dim=-1)
        hidden = dit.norm_out(hidden) * (1 + scale[:, None]) + shift[:, None]
        return head.action_decoder(dit.proj_out_2(hidden)[:, -actions.shape[1] :])

    def lerobot_own_sample(self, lerobot: nn.Module, observation: Any, noise: Tensor, steps: int) -> Tensor:
        buckets, size = lerobot.config.action_num_timestep_buckets, noise.shape[0]
        with torch.no_grad():
            prefix, actions = self.own_prefix(lerobot, observation), noise
            for step in range(steps):  # VLA-JEPA's grid (t = step / steps, its bucket int(1000 t)) and update
                bucket = torch.full((size,), int(step / steps * buckets), dtype=torch.long)
                s = torch.full((size,), 1 - step / steps)
                actions = actions + 1.0 / steps * self.own_prediction(lerobot, prefix, actions, bucket, s)
        return actions

    def lerobot_own_flow_matching_loss(
        self, lerobot: nn.Module, observation: Any, actions: Tensor, noise: Tensor, time: Tensor
    ) -> Tensor:
        own_time = 1 - time  # VLA-JEPA's path, bucket and target; its mean over every step (none padded here)
        x_t = (1 - own_time)[:, None, None] * noise + own_time[:, None, None] * actions
        bucket = (own_time * lerobot.config.action_num_timestep_buckets).long()
        prediction = self.own_prediction(lerobot, self.own_prefix(lerobot, observation), x_t, bucket, time)
        return F.mse_loss(prediction, actions - noise)

    def lerobot_chunk(self, lerobot: nn.Module, observation: Any, noise: Tensor) -> Tensor:
        """The chunk VLA-JEPA's action API samples: it draws its own noise after the prefix (seed 0, as
        :meth:`noise_like` draws it)."""
        torch.manual_seed(0)
        return lerobot.predict_action_chunk(observation)

    @pytest.mark.parametrize("steps", [4, 8])
    def test_its_own_sampler_is_the_teacher_mode_bit_for_bit(self, policy, batch, steps):
        """LeRobot's own action head's ``predict_action`` (its noise drawn after the prefix, its buckets, its update)
        is ``teacher-N`` on snapflow's grid, at VLA-JEPA's own 4 steps and at 8."""
        observation, actions = batch
        lerobot = policy.policy
        assert type(policy).own_steps(lerobot.config) == 4
        head, prefix = lerobot.model.action_model, self.own_prefix(lerobot, observation)
        head.num_inference_timesteps = steps
        torch.manual_seed(0)
        own = type(head).predict_action(head, prefix["tokens"], prefix["state"])
        assert torch.equal(
            own, sample_actions(policy, observation, self.noise_like(actions), SamplingMode(steps, jump=False))
        )

    @pytest.mark.parametrize("steps", [3, 4, 7, 10, 32, 100])
    def test_snapflows_grid_lands_on_vla_jepas_own_buckets(self, steps):
        """Each Euler step of teacher-N reads the bucket VLA-JEPA's own N-step sampler reads, int(1000 i / N)."""
        from snapflow.adapters.lerobot.vla_jepa import BUCKET_ROUNDING

        grid = torch.linspace(1, 0, steps + 1)[:-1]  # snapflow's float32 times, as its sampler makes them
        buckets = ((1 - grid) * 1000 + BUCKET_ROUNDING).long()
        assert buckets.tolist() == [int(i / steps * 1000) for i in range(steps)]

    def test_its_own_training_forward_is_the_adapters_loss_on_its_own_draws(self, policy):
        """LeRobot's own ``forward`` on a batch as its dataset gives it (each camera's and state's next frames for the
        world model, ``action_is_pad`` past an episode's end): its action loss (each row repeated
        ``repeated_diffusion_steps`` times, standard-normal noise, then its Beta(1.5, 1) times, from torch's global
        generator; a mean over the steps before the end) is the adapter's velocity's weighted squared error on those
        draws; its total adds the world model's loss, which the student's objective leaves out."""
        from snapflow.protocol import map_tensors

        lerobot = policy.policy
        observation = self.observations(self.batch_size, frames=FRAMES)
        padding = torch.zeros(self.batch_size, lerobot.config.chunk_size, dtype=torch.bool)
        padding[0, -2:] = padding[3, -1:] = True  # two episodes end inside their chunk
        observation["action_is_pad"] = padding
        torch.manual_seed(5)
        total, logs = lerobot.forward(observation)
        torch.manual_seed(5)  # the same draws, in the same order
        repeats = lerobot.config.repeated_diffusion_steps
        actions = policy.action_targets(observation).repeat(repeats, 1, 1)
        noise = torch.randn_like(actions)
        own_time = (0.999 - torch.distributions.Beta(1.5, 1.0).sample((actions.shape[0],))) / 0.999
        x_t = (1 - own_time)[:, None, None] * noise + own_time[:, None, None] * actions
        context = map_tensors(policy.encode(observation), lambda tensor: tensor.repeat(repeats, 1, 1))
        velocity = policy.velocity(x_t, 1 - own_time, 1 - own_time, context)
        weights = policy.action_weights(observation).repeat(repeats, 1, 1).expand_as(actions)
        ours = ((velocity - (noise - actions)).pow(2) * weights).sum() / weights.sum()
        torch.testing.assert_close(ours.item(), logs["action_loss"], rtol=1e-5, atol=1e-6)
        assert logs["wm_loss"] > 0 and total.item() == pytest.approx(logs["action_loss"] + logs["wm_loss"])

    def test_the_student_never_runs_the_world_model(self, policy, batch):
        """The world model (V-JEPA 2 and its predictor) is a training-time loss of LeRobot's own forward: neither the
        student's objective nor its samples run it, and the encoded prefix of a batch with the world model's frames
        is its current frame's."""
        calls = []
        model = policy.policy.model
        for module in (model.video_encoder, model.video_predictor):
            module.register_forward_hook(lambda *_: calls.append(1))
        observation, actions = batch
        SnapFlowObjective()(policy, observation, actions, generator=torch.Generator().manual_seed(0)).loss.backward()
        sample_actions(policy, observation, self.noise_like(actions), SamplingMode(4, jump=False))
        assert not calls
        frames = self.observations(self.batch_size, frames=FRAMES)
        current = {key: value[:, 0] if key.startswith("observation.") else value for key, value in frames.items()}
        ours, theirs = policy.encode(frames), policy.encode(current)
        assert ours.keys() == theirs.keys() and all(torch.equal(ours[key], theirs[key]) for key in ours)
        policy.policy.forward(frames)
        assert calls, "LeRobot's own forward runs it"

    def test_under_bfloat16_autocast_the_expert_runs_in_float32_and_every_expert_parameter_learns(self, policy, batch):
        """``lerobot-train`` with ``use_amp`` runs the student under bfloat16 autocast: VLA-JEPA's action head turns it
        off (an autocast to float32), and so does the velocity, so no weight cast in the objective's no-grad target
        pass is reused without a graph by its gradient pass."""
        observation, actions = batch
        with torch.autocast("cpu", dtype=torch.bfloat16):
            context = policy.encode(observation)
            velocity = policy.velocity(actions, torch.ones(4), torch.zeros(4), context)
            loss = SnapFlowObjective()(policy, observation, actions, generator=torch.Generator().manual_seed(0)).loss
        assert velocity.dtype == torch.float32 and loss.dtype == torch.float32
        loss.backward()
        expert = {id(parameter) for parameter in policy.expert_parameters()}
        assert all(p.grad is not None for p in policy.parameters() if id(p) in expert)

    def test_its_training_times_are_vla_jepas_own(self, policy):
        """Snapflow's draws of VLA-JEPA's times match the distribution of its own ``sample_time``, read as 1 - t,
        past 1 by up to a 1000th as its own are; another Beta is refused by name."""
        from dataclasses import replace

        from snapflow.adapters.lerobot.vla_jepa import VLAJEPATimeSampler
        from snapflow.errors import InvalidInputError

        sampler = type(policy).training_time_sampler(policy.policy.config)
        assert sampler == VLAJEPATimeSampler(1.5, 0.999)
        ours = sampler(200_000, generator=torch.Generator().manual_seed(0))
        torch.manual_seed(0)
        theirs = 1 - policy.policy.model.action_model.sample_time(200_000, torch.device("cpu"), torch.float32)
        quantiles = torch.linspace(0.01, 0.99, 50)
        torch.testing.assert_close(ours.quantile(quantiles), theirs.quantile(quantiles), atol=5e-3, rtol=0)
        assert 0 <= ours.min() and ours.max() <= 1 / 0.999
        with pytest.raises(InvalidInputError, match="Beta\\(1.5, 2.0\\)"):
            type(policy).training_time_sampler(replace(policy.policy.config, action_noise_beta_beta=2.0))

    def test_the_prompts_padding_is_kept_and_an_export_is_refused_by_name(self, policy):
        assert not policy.masks_prompt_padding and "builds its Qwen3-VL prompt" in type(policy).export_refusal


def test_the_checkpoint_writer_runs_as_a_module_and_its_folders_build_a_vla_jepa(vla_jepa_backbones, tmp_path):
    """``python -m snapflow.adapters.lerobot.vla_jepa_checkpoint DIR --size tiny --world-model``, as for a full-size
    one: its folders are what LeRobot's VLAJEPAPolicy loads its Qwen3-VL and V-JEPA 2 from, and the same seed writes
    the same weights."""
    import subprocess
    import sys

    from safetensors.torch import load_file

    from tests.lerobot_tiny_vla_jepa import build_tiny_vla_jepa

    module = "snapflow.adapters.lerobot.vla_jepa_checkpoint"
    command = [sys.executable, "-m", module, str(tmp_path), "--size", "tiny", "--world-model"]
    written = [
        Path(line) for line in subprocess.run(command, check=True, capture_output=True, text=True).stdout.split()
    ]
    assert written == [tmp_path / "qwen3_vl", tmp_path / "vjepa2"]
    assert build_tiny_vla_jepa(tuple(written)).model.video_encoder is not None
    for ours, fixture in zip(written, vla_jepa_backbones, strict=True):
        ours, fixture = load_file(ours / "model.safetensors"), load_file(fixture / "model.safetensors")
        assert ours.keys() == fixture.keys() and all(torch.equal(ours[name], fixture[name]) for name in ours)
