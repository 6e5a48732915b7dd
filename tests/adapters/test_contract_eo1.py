"""The adapter contract on LeRobot's EO-1 (lerobot >= 0.6.1), built offline at tiny size (tests/lerobot_tiny_eo1.py)."""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import torch
from torch import Tensor, nn

from snapflow import SNAPFLOW_1, SamplingMode, SnapFlowObjective, sample_actions
from tests.adapters.lerobot_contract import LeRobotAdapterContract
from tests.lerobot_tiny_eo1 import ACTION_DIM

OBS_STATE, ACTION = "observation.state", "action"


@contextlib.contextmanager
def own_draws(model: nn.Module, noise: Tensor | None = None, time: Tensor | None = None) -> Iterator[dict]:
    """EO-1's model draws its noise and times itself (``sample_noise``, ``sample_time``): these hand it ``noise`` and
    ``time`` where given, and record what it draws otherwise (the dict yielded)."""
    drawn: dict[str, Tensor] = {}
    own = type(model)

    def noise_of(shape: Any, device: Any) -> Tensor:
        return drawn.setdefault("noise", noise.clone() if noise is not None else own.sample_noise(model, shape, device))

    def time_of(size: int, device: Any) -> Tensor:
        return drawn.setdefault("time", time.clone() if time is not None else own.sample_time(model, size, device))

    model.sample_noise, model.sample_time = noise_of, time_of
    try:
        yield drawn
    finally:
        del model.sample_noise, model.sample_time


def sequence_inputs(observation: dict[str, Any]) -> dict[str, Any]:
    """What EO-1's ``forward`` and ``sample_actions`` read besides the state and the chunk."""
    return {key: value for key, value in observation.items() if key not in (OBS_STATE, ACTION)}


def velocity_by_hand(lerobot: nn.Module, observation: dict[str, Any], x_t: Tensor, t: Tensor) -> Tensor:
    """EO-1's velocity over its whole sequence, without a cache, as its training ``forward`` computes it: the prompt
    embedded with the state scattered in, the noisy chunk and the time scattered into the action span, Qwen2.5-VL over
    all of it, ``action_out_proj`` on the span."""
    model, ids = lerobot.model, {key: observation[key] for key in ("state_token_id", "action_token_id")}
    input_ids = observation["input_ids"]
    embeddings = model.embed_prefix(input_ids, states=lerobot.prepare_state(observation[OBS_STATE]), **ids)
    suffix = model.embed_suffix(t, x_t)
    _, span = model.get_placeholder_mask(input_ids, embeddings, action_features=suffix, **ids)
    hidden = model.vlm_backbone.model(
        input_ids=input_ids,
        attention_mask=observation["attention_mask"],
        inputs_embeds=embeddings.masked_scatter(span, suffix),
        pixel_values=observation["pixel_values"],
        image_grid_thw=observation["image_grid_thw"],
        mm_token_type_ids=observation["mm_token_type_ids"],
        use_cache=False,
    ).last_hidden_state
    return model.action_out_proj(hidden[span[..., 0]]).reshape(x_t.shape)


class TestEO1Adapter(LeRobotAdapterContract):
    """EO-1 samples by LeRobot's own ``sample_actions`` (a key/value cache of the prompt, then the action span alone
    each step): the reference sampler and loss are LeRobot's own, handed the contract's noise and times; the Euler
    sampler and the loss are also written out by hand over the whole sequence, without a cache, as EO-1's training
    ``forward`` runs it; and LeRobot's own ``predict_action_chunk`` and ``forward`` are checked on their own draws."""

    policy_type = "eo1"
    deploy_graphs = None  # Qwen2.5-VL's rotary positions are computed on the host
    capabilities = frozenset()

    @pytest.fixture(autouse=True)
    def _tiny_eo1(self, eo1_vlm: Path) -> None:
        self.eo1_vlm = eo1_vlm

    def build_lerobot(self) -> nn.Module:
        from tests.lerobot_tiny_eo1 import build_tiny_eo1

        return build_tiny_eo1(self.eo1_vlm)

    def observations(self, batch_size: int) -> dict[str, Any]:
        """As EO-1's pre-processor lays out a batch to sample (left-padded prompts, which LeRobot's own sampler needs),
        with the normalised chunks."""
        from tests.lerobot_tiny_eo1 import eo1_batch

        return eo1_batch(self.build_lerobot(), batch_size)

    @staticmethod
    def rows(observation: dict[str, Any], rows: slice) -> dict[str, Any]:
        from tests.lerobot_tiny_eo1 import eo1_rows

        return eo1_rows(observation, rows)

    def lerobot_own_sample(self, lerobot: nn.Module, observation: Any, noise: Tensor, steps: int) -> Tensor:
        """LeRobot's own ``EO1VisionFlowMatchingModel.sample_actions`` (the class's, not a student's sampler), its
        ``num_denoise_steps`` set to ``steps`` and its noise draw handed ``noise``."""
        model, before = lerobot.model, lerobot.config.num_denoise_steps
        lerobot.config.num_denoise_steps = steps
        try:
            with torch.no_grad(), own_draws(model, noise=noise):
                state = lerobot.prepare_state(observation[OBS_STATE])
                return type(model).sample_actions(model, states=state, **sequence_inputs(observation))
        finally:
            lerobot.config.num_denoise_steps = before

    def lerobot_own_flow_matching_loss(
        self, lerobot: nn.Module, observation: Any, actions: Tensor, noise: Tensor, time: Tensor
    ) -> Tensor:
        """LeRobot's own ``EO1VisionFlowMatchingModel.forward`` handed the contract's noise and times."""
        with own_draws(lerobot.model, noise=noise, time=time):
            state = lerobot.prepare_state(observation[OBS_STATE])
            return lerobot.model(states=state, action=actions, **sequence_inputs(observation))

    def lerobot_chunk(self, lerobot: nn.Module, observation: Any, noise: Tensor) -> Tensor:
        """The chunk EO-1's action API samples (it draws its noise after the prefix: seed 0, :meth:`noise_like`), at
        the padded width its model samples: ``predict_action_chunk`` cuts it to the robot's, which is checked."""
        model, sampled = lerobot.model, []
        sampler = model.sample_actions
        model.sample_actions = lambda **inputs: sampled.append(sampler(**inputs)) or sampled[-1]
        try:
            torch.manual_seed(0)
            chunk = lerobot.predict_action_chunk(observation)
        finally:
            model.sample_actions = sampler
        assert torch.equal(chunk, sampled[0][..., :ACTION_DIM].float())
        return sampled[0]

    @pytest.mark.parametrize("steps", [1, 2, 10])
    def test_its_own_predict_action_chunk_is_the_teacher_mode(self, policy, batch, steps):
        """An unwrapped EO-1's own ``predict_action_chunk`` (its normal noise drawn after the prefix, its grid
        1 + k dt and its update) is ``teacher-N``: bit for bit where snapflow's grid is LeRobot's (1 and 2 steps),
        within float32 rounding of the grid's times otherwise."""
        observation, actions = batch
        teacher = self.build_lerobot()
        teacher.config.num_denoise_steps = steps
        torch.manual_seed(0)
        own = teacher.predict_action_chunk(observation)
        ours = sample_actions(policy, observation, self.noise_like(actions), SamplingMode(steps, jump=False))
        assert type(policy).own_steps(policy.policy.config) == 10
        if steps <= 2:
            assert torch.equal(own, ours[..., :ACTION_DIM])
        torch.testing.assert_close(own, ours[..., :ACTION_DIM], atol=1e-5, rtol=1e-5)

    def test_a_hand_written_euler_over_the_whole_sequence_is_the_teacher_mode(self, policy, batch):
        """Euler from t = 1 by hand, each velocity over EO-1's whole sequence without a cache (as its training forward
        runs it): ``teacher-4`` through the adapter's cache, rounding apart."""
        observation, actions = batch
        lerobot, x = policy.policy, self.noise_like(actions)
        expected = sample_actions(policy, observation, x, SamplingMode(4, jump=False))
        with torch.no_grad():
            for step in range(4):
                x = x - 0.25 * velocity_by_hand(lerobot, observation, x, torch.full((x.shape[0],), 1 - step / 4))
        torch.testing.assert_close(x, expected, atol=1e-5, rtol=1e-5)

    def test_a_hand_written_loss_is_lerobots_forward_and_the_objectives_flow_matching(self, policy, batch):
        """x_t = t noise + (1 - t) a, target noise - a, the squared error's mean over every entry of the padded chunk
        (EO-1's default supervises its padding): LeRobot's own ``forward`` on the same draws, and the objective's
        flow-matching branch through the adapter's cache."""
        observation, actions = batch
        noise, time = self.noise_like(actions), torch.tensor([0.9, 0.6, 0.3, 0.05])
        x_t = time[:, None, None] * noise + (1 - time[:, None, None]) * actions
        by_hand = (velocity_by_hand(policy.policy, observation, x_t, time) - (noise - actions)).pow(2).mean()
        own = self.lerobot_own_flow_matching_loss(policy.policy, observation, actions, noise, time)
        ours = SnapFlowObjective(alpha=1.0)(policy, observation, actions, noise=noise, time=time).flow_matching_loss
        torch.testing.assert_close(own, by_hand)
        torch.testing.assert_close(ours, by_hand, atol=1e-5, rtol=1e-5)

    @pytest.mark.parametrize("supervise", [True, False])
    def test_its_own_forward_on_a_training_batch_is_the_adapters_loss_on_its_own_draws(self, policy, supervise):
        """A training batch as the pre-processor lays it out (right-padded prompts: each row's action span where its
        prompt ends) and LeRobot's own ``forward`` with its own draws (Beta(1.5, 1) * 0.999 + 0.001, a standard
        normal): the adapter's velocity, its prompts moved to the left, gives the same weighted loss. With
        ``supervise_padding_*`` off, EO-1 leaves the padded width and the steps past an episode's end out of its loss
        and those steps' tokens out of the attention; so do the adapter's weights and context."""
        from tests.lerobot_tiny_eo1 import eo1_batch

        lerobot, config = policy.policy, policy.policy.config
        config.supervise_padding_action_dims = config.supervise_padding_actions = supervise
        observation = eo1_batch(lerobot, 4, training=True)
        assert not bool(observation["attention_mask"][:, -1].all()), "the training batch is right-padded"
        observation["action_is_pad"] = torch.tensor(
            [[False] * 4, [False] * 3 + [True], [False] * 4, [False, True, True, True]]
        )
        actions = policy.action_targets(observation)
        with own_draws(lerobot.model) as drawn:
            own, _ = lerobot.forward(observation)
        noise, time = drawn["noise"], drawn["time"]
        x_t = time[:, None, None] * noise + (1 - time[:, None, None]) * actions
        squared = (policy.velocity(x_t, time, time, policy.encode(observation)) - (noise - actions)).pow(2)
        weights = policy.action_weights(observation)
        if supervise:
            assert weights is None
            ours = squared.mean()
        else:
            weights = weights.expand_as(squared).float()
            assert weights.sum() == (4 + 3 + 4 + 1) * ACTION_DIM
            ours = (squared * weights).sum() / weights.sum()
        torch.testing.assert_close(ours, own, atol=1e-5, rtol=1e-5)

    def test_a_right_padded_batch_samples_what_its_left_padded_one_does(self, policy):
        """Sampling a training batch's layout: the adapter moves each prompt's padding to its left, where EO-1's own
        sampler (which needs the action spans aligned) refuses it."""
        from tests.lerobot_tiny_eo1 import eo1_batch

        left, right = (eo1_batch(policy.policy, 4, training=training) for training in (False, True))
        noise = self.noise_like(policy.action_targets(left))
        for mode in (SamplingMode(2, jump=False), SNAPFLOW_1):
            torch.testing.assert_close(
                sample_actions(policy, right, noise, mode), sample_actions(policy, left, noise, mode)
            )
        with pytest.raises(ValueError, match="share the same action token mask"):
            self.lerobot_own_sample(policy.policy, right, noise, 1)

    def test_under_bfloat16_autocast_one_objective_step_reaches_every_expert_parameter(self, policy, batch):
        """``lerobot-train --policy.use_amp=true`` runs the student under bfloat16 autocast, on the CPU too: the
        objective's no-grad target pass must leave no cast weight in autocast's cache for its gradient pass to reuse
        without a graph."""
        observation, actions = batch
        trainable = {id(parameter) for parameter in policy.expert_parameters()}
        for parameter in policy.parameters():
            parameter.requires_grad_(id(parameter) in trainable)
        with torch.autocast("cpu", dtype=torch.bfloat16):
            loss = SnapFlowObjective()(policy, observation, actions, generator=torch.Generator().manual_seed(0)).loss
        loss.backward()
        missing = [name for name, p in policy.named_parameters() if id(p) in trainable and p.grad is None]
        assert not missing

    def test_its_training_times_are_openpis_beta_and_other_ones_are_refused_by_name(self, policy):
        from snapflow.errors import InvalidInputError
        from snapflow.flow.time_sampling import BetaTimeSampler

        config = policy.policy.config
        assert type(policy).training_time_sampler(config) == BetaTimeSampler(concentration=1.5, min_time=0.001)
        config.time_sampling_scale = 0.9
        with pytest.raises(InvalidInputError, match="does not reach t = 1"):
            type(policy).training_time_sampler(config)

    def test_it_runs_its_backbone_in_bfloat16_as_its_own_dtype_option_does(self, policy, batch):
        from snapflow.errors import InvalidInputError

        observation, actions = batch
        policy.run_in(torch.bfloat16)
        model = policy.policy.model
        assert model.vlm_backbone.dtype == torch.bfloat16 and model.action_out_proj.dtype == torch.float32
        chunk = sample_actions(policy, observation, self.noise_like(actions), SNAPFLOW_1)
        assert chunk.dtype == torch.float32 and torch.isfinite(chunk).all()
        with pytest.raises(InvalidInputError, match="only through autocast"):
            policy.run_in(torch.float16)

    def test_an_export_is_refused_by_name(self, policy):
        assert "rotary positions" in type(policy).export_refusal


def test_the_checkpoint_writer_runs_as_a_module_and_its_folder_builds_an_eo1(eo1_vlm, tmp_path):
    """``python -m snapflow.adapters.lerobot.eo1_checkpoint DIR --size tiny``, as for a full-size one: its folder is
    what LeRobot's EO1Policy loads its Qwen2.5-VL and processor from, and the same seed writes the same weights. At
    full size it is Qwen2.5-VL-3B's 3,754,622,976 parameters (counted on the meta device, nothing allocated)."""
    import subprocess
    import sys

    from safetensors.torch import load_file

    from snapflow.adapters.lerobot.eo1_checkpoint import parameter_count
    from tests.lerobot_tiny_eo1 import build_tiny_eo1, eo1_batch

    command = [sys.executable, "-m", "snapflow.adapters.lerobot.eo1_checkpoint", str(tmp_path), "--size", "tiny"]
    written = Path(subprocess.run(command, check=True, capture_output=True, text=True).stdout.strip())
    assert written == tmp_path
    assert eo1_batch(build_tiny_eo1(written), 1)["image_grid_thw"].tolist() == [[1, 4, 4]]  # 16 patches, 4 tokens
    ours, fixture = (load_file(folder / "model.safetensors") for folder in (written, eo1_vlm))
    assert ours.keys() == fixture.keys() and all(torch.equal(ours[name], fixture[name]) for name in ours)
    assert parameter_count("full") == 3_754_622_976
