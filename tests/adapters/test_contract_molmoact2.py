"""The adapter contract on LeRobot's MolmoAct2 (lerobot >= 0.6.1), built offline at tiny size
(tests/lerobot_tiny_molmoact2.py)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
import torch
from torch import Tensor, nn

from snapflow import SamplingMode, sample_actions
from tests.adapters.lerobot_contract import LeRobotAdapterContract
from tests.lerobot_tiny_molmoact2 import ACTION_DIM, HORIZON, MAX_ACTION_DIM


def own_times(lerobot: nn.Module, count: int) -> Tensor:
    """``count`` of MolmoAct2's own training times (t = 0 noise), drawn by LeRobot's own sampler of them from torch's
    global generator, as its training forward draws them."""
    from snapflow.adapters.lerobot.base import modeling_module

    config = lerobot.config
    return modeling_module(lerobot)._sample_beta_timesteps(
        batch_size=count,
        device=torch.device("cpu"),
        cutoff=config.flow_matching_cutoff,
        time_offset=config.flow_matching_time_offset,
        time_scale=config.flow_matching_time_scale,
        alpha=config.flow_matching_beta_alpha,
        beta=config.flow_matching_beta_beta,
    )


class TestMolmoAct2Adapter(LeRobotAdapterContract):
    """MolmoAct2 runs its flow the other way (t = 0 noise) from a standard normal zero on the padded action width: its
    "own" Euler and training loss are written out here by hand from LeRobot's action expert, as its
    ``generate_actions_from_inputs`` and training forward run it, on its own prefix (the VLM's per-layer keys and
    values through ``prepare_context``); phi_s(s) is added to the expert's time conditioning, as the student's velocity
    adds it. The tests below check the adapter against LeRobot's own sampler and ``forward`` themselves."""

    policy_type = "molmoact2"
    deploy_graphs = None  # its prefix lays its image crops out on the host
    capabilities = frozenset({"OwnNoise"})

    @pytest.fixture(autouse=True)
    def _tiny_molmoact2(self, molmoact2_checkpoint: Path) -> None:
        self.checkpoint = molmoact2_checkpoint

    def build_lerobot(self) -> nn.Module:
        from tests.lerobot_tiny_molmoact2 import build_tiny_molmoact2

        return build_tiny_molmoact2(self.checkpoint)

    def observations(self, batch_size: int) -> dict[str, Any]:
        from tests.lerobot_tiny_molmoact2 import raw_molmoact2_batch, tiny_molmoact2_processors

        preprocessor, _ = tiny_molmoact2_processors(self.build_lerobot())
        return preprocessor(raw_molmoact2_batch(batch_size))

    @staticmethod
    def rows(observation: dict[str, Any], rows: slice) -> dict[str, Any]:
        from tests.lerobot_tiny_molmoact2 import molmoact2_rows

        return molmoact2_rows(observation, rows)

    @staticmethod
    def noise_like(actions: Tensor, seed: int = 0) -> Tensor:
        """MolmoAct2's noise: a standard normal, zero past the robot's 4-D actions (as torch.manual_seed(seed) draws
        it)."""
        noise = torch.randn(actions.shape, generator=torch.Generator().manual_seed(seed))
        return noise * (torch.arange(actions.shape[-1]) < ACTION_DIM)

    @staticmethod
    def own_prefix(lerobot: nn.Module, observation: Any) -> Any:
        """``generate_actions_from_inputs`` up to its loop: the VLM's cache, its keys and values by layer, the
        encoder's mask and the expert's ``prepare_context``."""
        backbone, expert = lerobot._backbone(), lerobot._action_expert()
        inputs = lerobot._model_inputs(observation)
        with torch.no_grad():
            outputs = backbone(**inputs, use_cache=True)
            layers = backbone._extract_kv_states(outputs.past_key_values)
            mask = backbone._get_encoder_attention_mask(inputs["input_ids"], inputs["attention_mask"])
            size = inputs["input_ids"].shape[0]
            return expert.prepare_context(
                encoder_kv_states=layers,
                encoder_attention_mask=mask,
                batch_size=size,
                seq_len=HORIZON,
                device=torch.device("cpu"),
                dtype=torch.float32,
            )

    def lerobot_own_sample(self, lerobot: nn.Module, observation: Any, noise: Tensor, steps: int) -> Tensor:
        expert, width = lerobot._action_expert(), ~observation["action_dim_is_pad"][:, None, :]
        context, x = self.own_prefix(lerobot, observation), noise.masked_fill(~width, 0)
        with torch.no_grad():
            for step in range(steps):  # MolmoAct2's grid (t = step / steps, from noise) and update, width masked
                time = torch.full((noise.shape[0],), step / steps)
                velocity = expert.forward_with_context(x, time, context=context).masked_fill(~width, 0)
                x = (x + 1.0 / steps * velocity).masked_fill(~width, 0)
        return x

    def lerobot_own_flow_matching_loss(
        self, lerobot: nn.Module, observation: Any, actions: Tensor, noise: Tensor, time: Tensor
    ) -> Tensor:
        own_time = (1 - time)[:, None, None]  # MolmoAct2's path: its time from the noise; its target data - noise
        x_t = (1 - own_time) * noise + own_time * actions
        context = self.own_prefix(lerobot, observation)
        prediction = lerobot._action_expert().forward_with_context(x_t, 1 - time, context=context)
        width = (~observation["action_dim_is_pad"][:, None, :]).float()
        error = (prediction - (actions - noise)).pow(2)
        return ((error * width).sum(-1) / width.sum(-1)).mean()  # each step's mean over the width, then the steps'

    def entry_weights(self, observation: Any, actions: Tensor) -> Tensor:
        """MolmoAct2's width mask: its padded action width weighs nothing."""
        width = (~observation["action_dim_is_pad"][:, None, :]).float().expand_as(actions)
        assert 0 < width.sum() < width.numel(), "the tiny MolmoAct2's chunks hold padding"
        return width

    def lerobot_chunk(self, lerobot: nn.Module, observation: Any, noise: Tensor) -> Tensor:
        """The chunk MolmoAct2's action API samples: it draws its own noise after the prefix (seed 0,
        :meth:`noise_like`) and cuts the chunk to the robot's width, whose padding (zero) is put back."""
        torch.manual_seed(0)
        chunk = lerobot.predict_action_chunk(observation)
        return torch.nn.functional.pad(chunk, (0, MAX_ACTION_DIM - chunk.shape[-1]))

    @pytest.mark.parametrize("steps", [1, 2, 10])
    def test_its_own_sampler_is_the_teacher_mode(self, policy, batch, steps):
        """LeRobot's own ``generate_actions_from_inputs`` (its noise drawn after the prefix from its generator, its
        grid, its masks) is ``teacher-N``: bit for bit where its times are snapflow's (1, 1/2), within rounding at its
        own 10 (1 - 0.1 k in float32 is not k / 10 to the last bit)."""
        observation, actions = batch
        lerobot = policy.policy
        backbone = lerobot._backbone()
        own = type(backbone).generate_actions_from_inputs(
            backbone,
            **lerobot._model_inputs(observation),
            action_dim_is_pad=observation["action_dim_is_pad"],
            action_horizon=HORIZON,
            num_steps=steps,
            generator=torch.Generator().manual_seed(0),
        )
        ours = sample_actions(policy, observation, self.noise_like(actions), SamplingMode(steps, jump=False))
        if steps <= 2:
            assert torch.equal(ours, own)
        torch.testing.assert_close(ours, own, atol=1e-5, rtol=0)
        assert not ours[..., ACTION_DIM:].any(), "the padded width stays zero"

    @pytest.mark.parametrize("past_the_end", [False, True])
    def test_its_own_training_forward_is_the_adapters_velocity_on_its_own_draws(self, policy, past_the_end):
        """LeRobot's own ``forward`` (its 8 draws of a time and a noise a sample from torch's global generator, its
        masks, each step's mean over the width, the chunk's over all its steps) is the adapter's velocity's squared
        error on those draws; chunks past an episode's end mask the expert as MolmoAct2's training forward does."""
        from tests.lerobot_tiny_molmoact2 import raw_molmoact2_batch, tiny_molmoact2_processors

        lerobot, raw = policy.policy, raw_molmoact2_batch(4)
        if past_the_end:
            raw["action_is_pad"] = torch.arange(HORIZON)[None, :] >= torch.tensor([[4], [3], [2], [4]])
        observation = tiny_molmoact2_processors(lerobot)[0](raw)
        assert bool(observation["action_horizon_is_pad"].any()) == past_the_end
        torch.manual_seed(5)
        own, _ = lerobot.forward(observation)
        torch.manual_seed(5)  # the same draws, in the same order
        draws, size = lerobot.config.num_flow_timesteps, 4
        time = own_times(lerobot, size * draws).view(size, draws)
        width = (~observation["action_dim_is_pad"][:, None, :]).float()
        noise = torch.randn(size, draws, HORIZON, MAX_ACTION_DIM) * width[:, None]
        actions, context = policy.action_targets(observation), policy.encode(observation)
        weights = policy.action_weights(observation)
        errors = []
        for draw in range(draws):
            own_time = time[:, draw, None, None]
            x_t = (1 - own_time) * noise[:, draw] + own_time * actions
            velocity = policy.velocity(x_t, 1 - time[:, draw], 1 - time[:, draw], context)
            errors.append(((velocity - (noise[:, draw] - actions)).pow(2) * weights).sum(-1) / width.sum(-1))
        # to rounding: without the masks the valid steps' self-attention reads the steps past the end
        torch.testing.assert_close(torch.stack(errors, 1).mean(), own, atol=1e-7, rtol=1e-7)

    def test_its_training_times_are_molmoact2s_shifted_beta(self, policy):
        """MolmoAct2's 0.001 + 0.999 Beta(1, 1.5) in snapflow's direction is 0.999 Beta(1.5, 1), drawn from the
        caller's generator: the same distribution as LeRobot's own draws (quantiles of 20,000 of each)."""
        from snapflow.adapters.lerobot.molmoact2 import MolmoAct2TimeSampler

        config = policy.policy.config
        sampler = type(policy).training_time_sampler(config)
        assert sampler == MolmoAct2TimeSampler(1.5, 0.0, 0.999)
        ours = sampler(20_000, generator=torch.Generator().manual_seed(0))
        assert torch.equal(ours, sampler(20_000, generator=torch.Generator().manual_seed(0)))
        torch.manual_seed(0)
        own = own_times(policy.policy, 20_000)
        levels = torch.tensor([0.05, 0.25, 0.5, 0.75, 0.95])
        torch.testing.assert_close(ours.quantile(levels), (1 - own).quantile(levels), atol=0.02, rtol=0)
        assert 0 <= ours.min() and ours.max() <= 0.999

    def test_times_and_heads_it_cannot_distil_are_refused_by_name(self, policy):
        from snapflow.adapters.lerobot.molmoact2 import MolmoAct2FlowPolicy
        from snapflow.errors import InvalidInputError

        config = policy.policy.config
        config.flow_matching_beta_alpha = 2.0
        with pytest.raises(InvalidInputError, match=r"Beta\(2.0, 1.5\)"):
            MolmoAct2FlowPolicy.training_time_sampler(config)
        config.flow_matching_beta_alpha, config.inference_action_mode = 1.0, "discrete"
        with pytest.raises(InvalidInputError, match="discrete FAST tokens, one at a time"):
            MolmoAct2FlowPolicy(policy.policy)

    def test_its_flow_starts_from_its_own_noise_zero_on_the_padded_width(self, policy):
        from snapflow.protocol import draw_flow_noise

        noise = draw_flow_noise(policy, (3, HORIZON, MAX_ACTION_DIM), torch.Generator().manual_seed(0))
        assert torch.equal(noise, self.noise_like(torch.zeros(3, HORIZON, MAX_ACTION_DIM)))
        assert noise[..., :ACTION_DIM].abs().sum() > 0 and not noise[..., ACTION_DIM:].any()

    def test_a_config_naming_no_steps_samples_its_checkpoints(self, policy):
        """LeRobot's config leaves ``num_inference_steps`` unset by default: the checkpoint's own 10 then."""
        config = policy.policy.config
        config.num_inference_steps = None
        assert type(policy).own_steps(config) == 10

    def test_a_frame_repeated_is_its_rows_repeated(self, policy):
        """The example frame (bench's) lays its image tensors out by rows, so that a batch of it repeated samples the
        same chunk in every row."""
        frame = policy.example_observation(torch.device("cpu"))
        repeated = {key: value.expand(3, *value.shape[1:]).clone() for key, value in frame.items()}
        noise = self.noise_like(torch.zeros(1, HORIZON, MAX_ACTION_DIM))
        one = sample_actions(policy, frame, noise, SamplingMode(1, jump=True))
        three = sample_actions(policy, repeated, noise.expand(3, -1, -1), SamplingMode(1, jump=True))
        # A batch of three takes other matmul kernels than a batch of one (1.1e-6 apart on CI's CPU); rows laid out
        # wrongly differ by the distance between frames, orders of magnitude more.
        torch.testing.assert_close(three, one.expand(3, -1, -1), atol=1e-5, rtol=0)

    def test_an_export_is_refused_by_name(self, policy):
        assert "lays each row's image crops" in type(policy).export_refusal


def test_the_checkpoint_writer_runs_as_a_module_and_counts_its_parameters(molmoact2_checkpoint, tmp_path):
    """``python -m snapflow.adapters.lerobot.molmoact2_checkpoint DIR --size tiny``, as for a full-size one: its folder
    is what LeRobot's MolmoAct2Policy loads, the same seed writes the same weights, and the parameter count computed
    from the config alone (how the full size is counted, never built here) is the built model's."""
    import subprocess
    import sys

    from safetensors.torch import load_file

    from snapflow.adapters.lerobot.molmoact2_checkpoint import parameter_count
    from tests.lerobot_tiny_molmoact2 import build_tiny_molmoact2

    command = [sys.executable, "-m", "snapflow.adapters.lerobot.molmoact2_checkpoint", str(tmp_path), "--size", "tiny"]
    written = Path(subprocess.run(command, check=True, capture_output=True, text=True).stdout.strip())
    assert written == tmp_path
    ours, fixture = (load_file(folder / "model.safetensors") for folder in (written, molmoact2_checkpoint))
    assert ours.keys() == fixture.keys() and all(torch.equal(ours[name], fixture[name]) for name in ours)
    model = build_tiny_molmoact2(written).model
    assert sum(parameter_count("tiny").values()) == sum(parameter.numel() for parameter in model.parameters())
    expert = model.model.action_expert
    assert parameter_count("tiny")["action_expert"] == sum(parameter.numel() for parameter in expert.parameters())
