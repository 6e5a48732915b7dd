"""The adapter contract on LeRobot's EVO1 (lerobot >= 0.6.1), built offline at tiny size (tests/lerobot_tiny_evo1.py)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
import torch
from torch import Tensor, nn

from snapflow import SamplingMode, sample_actions
from tests.adapters.lerobot_contract import LeRobotAdapterContract
from tests.lerobot_tiny_evo1 import ACTION_DIM


class TestEvo1Adapter(LeRobotAdapterContract):
    """EVO1 runs its flow the other way (t = 0 noise) on whole rows of its time table, from uniform noise: its "own"
    Euler and training loss are written out here by hand from LeRobot's action head, as its ``get_action`` and
    ``forward`` run them, on its own prefix (the VLM's fused tokens and ``_prepare_context``); phi_s(s) is added to
    the time's row, as the student's velocity adds it. The tests below check the adapter against LeRobot's own
    ``get_action`` and ``forward`` themselves."""

    policy_type = "evo1"
    deploy_graphs = None  # EVO1 tokenizes its prompt on the host, inside the prefix
    capabilities = frozenset({"OwnNoise"})
    selected_action_width = 8  # max_action_dim: EVO1's post-processor cuts it to the robot's

    @pytest.fixture(autouse=True)
    def _tiny_evo1(self, evo1_vlm: Path) -> None:
        self.evo1_vlm = evo1_vlm

    def build_lerobot(self) -> nn.Module:
        from tests.lerobot_tiny_evo1 import build_tiny_evo1

        return build_tiny_evo1(self.evo1_vlm)

    def observations(self, batch_size: int) -> dict[str, Any]:
        from tests.lerobot_tiny_evo1 import raw_evo1_batch, tiny_evo1_processors

        preprocessor, _ = tiny_evo1_processors(self.build_lerobot())
        return preprocessor(raw_evo1_batch(batch_size))

    @staticmethod
    def rows(observation: dict[str, Any], rows: slice) -> dict[str, Any]:
        from tests.lerobot_tiny_evo1 import evo1_rows

        return evo1_rows(observation, rows)

    @staticmethod
    def noise_like(actions: Tensor, seed: int = 0) -> Tensor:
        """EVO1's noise: uniform in [-1, 1], zero past the robot's 4-D actions (as torch.manual_seed(seed) draws it)."""
        noise = torch.rand(actions.shape, generator=torch.Generator().manual_seed(seed)) * 2 - 1
        return noise * (torch.arange(actions.shape[-1]) < ACTION_DIM)

    @staticmethod
    def own_prefix(lerobot: nn.Module, observation: Any) -> dict[str, Any]:
        """EVO1's ``predict_action_chunk`` up to its head's loop: the fused tokens, ``_prepare_context``, the mask."""
        states, _ = lerobot._prepare_state(observation)
        size, head = states.shape[0], lerobot.model.action_head
        with torch.no_grad():
            fused, context_mask = lerobot._compute_fused_tokens(
                lerobot._normalize_task_batch(observation), *lerobot._collect_image_batches(observation)
            )
            tokens, padding, embodiment = head._prepare_context(
                fused, states, lerobot._get_embodiment_ids(observation, size), context_mask
            )
        mask = lerobot._prepare_inference_action_mask(size)[:, None].float()
        return {"tokens": tokens, "padding": padding, "embodiment": embodiment, "mask": mask}

    @staticmethod
    def own_prediction(lerobot: nn.Module, prefix: dict[str, Any], seq: Tensor, row: Tensor, s: Tensor) -> Tensor:
        """EVO1's ``predict_velocity`` (data - noise) at its table's ``row``, phi_s(s) added to the row (where the
        policy is wrapped)."""
        head, mask = lerobot.model.action_head, prefix["mask"]
        time_emb = head.time_pos_enc.pe[0, row]
        if hasattr(lerobot.model, "target_time_embedding"):
            time_emb = time_emb + lerobot.model.target_time_embedding(s)
        x = head._project_actions(seq * mask, prefix["embodiment"])
        for block in head.transformer_blocks:
            x = block(x, prefix["tokens"], time_emb, prefix["padding"])
        pooled = head.seq_pool_proj(head.norm_out(x).reshape(seq.shape[0], -1))
        return head.mlp_head(pooled, prefix["embodiment"]).view(seq.shape) * mask

    def lerobot_own_sample(self, lerobot: nn.Module, observation: Any, noise: Tensor, steps: int) -> Tensor:
        with torch.no_grad():
            prefix, seq = self.own_prefix(lerobot, observation), noise * self.own_prefix(lerobot, observation)["mask"]
            for step in range(steps):  # EVO1's grid (t = step / steps, its row int(999 t)) and update
                row = torch.full((noise.shape[0],), int(step / steps * 999))
                s = torch.full((noise.shape[0],), 1 - step / steps)
                seq = seq + 1.0 / steps * self.own_prediction(lerobot, prefix, seq, row, s)
        return seq * prefix["mask"]

    def lerobot_own_flow_matching_loss(
        self, lerobot: nn.Module, observation: Any, actions: Tensor, noise: Tensor, time: Tensor
    ) -> Tensor:
        own_time = (1 - time)[:, None, None]  # EVO1's path and row; its squared error's sum over its mask's entries
        _, mask = lerobot._prepare_actions(observation)
        mask = mask.float()
        x_t = (1 - own_time) * noise * mask + own_time * actions * mask
        row = (own_time[:, 0, 0] * 999).long()
        prefix = {**self.own_prefix(lerobot, observation), "mask": mask}
        prediction = self.own_prediction(lerobot, prefix, x_t, row, time)
        return ((prediction - (actions - noise) * mask) * mask).pow(2).sum() / mask.sum()

    def entry_weights(self, observation: Any, actions: Tensor) -> Tensor:
        """EVO1's mask: its padded width weighs nothing."""
        mask = observation["action_mask"].float()
        assert 0 < mask.sum() < mask.numel(), "the tiny EVO1's chunks hold padding"
        return mask

    def lerobot_chunk(self, lerobot: nn.Module, observation: Any, noise: Tensor) -> Tensor:
        """The chunk EVO1's action API samples: it draws its own noise after the prefix (seed 0, :meth:`noise_like`)."""
        torch.manual_seed(0)
        return lerobot.predict_action_chunk(observation)

    @pytest.mark.parametrize("steps", [4, 32])
    def test_its_own_sampler_is_the_teacher_mode_bit_for_bit(self, policy, batch, steps):
        """LeRobot's own ``get_action`` (its uniform noise drawn after the prefix, its rows, its update) is
        ``teacher-N`` on snapflow's grid, at EVO1's own 32 steps and at 4."""
        observation, actions = batch
        lerobot = policy.policy
        assert type(policy).own_steps(lerobot.config) == 32
        head, prefix = lerobot.model.action_head, self.own_prefix(lerobot, observation)
        head.num_inference_timesteps = steps
        fused = lerobot._compute_fused_tokens(
            lerobot._normalize_task_batch(observation), *lerobot._collect_image_batches(observation)
        )
        torch.manual_seed(0)
        own = (
            type(head)
            .get_action(
                head,
                fused[0],
                state=lerobot._prepare_state(observation)[0],
                embodiment_id=prefix["embodiment"],
                action_mask=lerobot._prepare_inference_action_mask(actions.shape[0]),
                context_mask=fused[1],
            )
            .view(actions.shape)
        )
        assert torch.equal(
            own, sample_actions(policy, observation, self.noise_like(actions), SamplingMode(steps, jump=False))
        )

    @pytest.mark.parametrize("steps", [3, 4, 7, 10, 32, 100])
    def test_snapflows_grid_lands_on_evo1s_own_rows(self, policy, batch, steps):
        """Each Euler step of teacher-N reads the row EVO1's own N-step sampler reads, int(999 i / N)."""
        from snapflow.adapters.lerobot.evo1 import ROW_ROUNDING, TIME_ROWS

        grid = torch.linspace(1, 0, steps + 1)[:-1]  # snapflow's float32 times, as its sampler makes them
        rows = torch.floor((1 - grid) * (TIME_ROWS - 1) + ROW_ROUNDING).long()
        assert rows.tolist() == [int(i / steps * 999) for i in range(steps)]

    def test_its_own_training_forward_is_the_adapters_loss_on_its_own_draws(self, policy, batch):
        """LeRobot's own ``forward`` (its Beta(2, 2) time and uniform noise from torch's global generator, its mask,
        its sum over the mask by the count) is the adapter's velocity's weighted squared error on those draws."""
        observation, actions = batch
        lerobot = policy.policy
        torch.manual_seed(5)
        own, _ = lerobot.forward(observation)
        torch.manual_seed(5)  # the same draws, in the same order
        time = torch.distributions.Beta(2, 2).sample((actions.shape[0],)).clamp(0.02, 0.98)
        weights = policy.action_weights(observation)
        noise = (torch.rand_like(actions) * 2 - 1) * weights
        own_time = time[:, None, None]
        x_t = (1 - own_time) * noise + own_time * actions
        velocity = policy.velocity(x_t, 1 - time, 1 - time, policy.encode(observation))
        ours = ((velocity - (noise - actions)) * weights).pow(2).sum() / weights.sum()
        torch.testing.assert_close(ours, own)

    def test_under_bfloat16_autocast_one_objective_step_reaches_every_expert_parameter(self, policy, batch):
        """``lerobot-train`` runs EVO1 (``use_amp``) under bfloat16 autocast, on the CPU too: the objective's no-grad
        target pass must leave no cast weight in autocast's cache for its gradient pass to reuse without a graph."""
        from snapflow import SnapFlowObjective

        observation, actions = batch
        with torch.autocast("cpu", dtype=torch.bfloat16):
            loss = SnapFlowObjective()(policy, observation, actions, generator=torch.Generator().manual_seed(0)).loss
        loss.backward()
        missing = [name for name, p in policy.named_parameters() if p.requires_grad and p.grad is None]
        expert = {id(parameter) for parameter in policy.expert_parameters()}
        assert not [name for name, p in policy.named_parameters() if id(p) in expert and p.grad is None], missing

    def test_its_training_times_are_evo1s_clamped_beta_two_two(self, policy):
        from snapflow.flow.time_sampling import Beta22TimeSampler

        assert type(policy).training_time_sampler(policy.policy.config) == Beta22TimeSampler(0.02, 0.98)

    def test_its_flow_starts_from_its_own_uniform_noise_zero_on_the_padded_width(self, policy):
        from snapflow.protocol import draw_flow_noise

        noise = draw_flow_noise(policy, (3, 4, 8), torch.Generator().manual_seed(0))
        assert torch.equal(noise, self.noise_like(torch.zeros(3, 4, 8)))
        assert noise[..., :ACTION_DIM].abs().max() <= 1 and not noise[..., ACTION_DIM:].any()

    def test_an_export_is_refused_by_name(self, policy):
        assert "tokenizes the task's text" in type(policy).export_refusal


def test_the_checkpoint_writer_runs_as_a_module_and_its_folder_builds_an_evo1(evo1_vlm, tmp_path):
    """``python -m snapflow.adapters.lerobot.evo1_checkpoint DIR --size tiny``, as for a full-size one: its folder is
    what LeRobot's Evo1Policy loads its InternVL3 from, and the same seed writes the same weights."""
    import subprocess
    import sys

    from safetensors.torch import load_file

    from tests.lerobot_tiny_evo1 import build_tiny_evo1

    command = [sys.executable, "-m", "snapflow.adapters.lerobot.evo1_checkpoint", str(tmp_path), "--size", "tiny"]
    written = Path(subprocess.run(command, check=True, capture_output=True, text=True).stdout.strip())
    assert written == tmp_path
    assert build_tiny_evo1(written).model.embedder.num_image_token == 1
    ours, fixture = (load_file(folder / "model.safetensors") for folder in (written, evo1_vlm))
    assert ours.keys() == fixture.keys() and all(torch.equal(ours[name], fixture[name]) for name in ours)
