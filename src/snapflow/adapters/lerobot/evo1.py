"""LeRobot's Evo1Policy (EVO1) under SnapFlow (LeRobot >= 0.6.1).

EVO1 encodes the observation once: InternVL3 (its vision tower and its language model cut to ``vlm_num_layers``) fuses
the cameras and the task, which EVO1 tokenizes itself, and the state encoder appends the state as one more token
(``_prepare_context``): the frozen prefix. Each step its action encoder reads the noisy chunk, transformer blocks
cross-attend to the prefix, and ``norm_out``, ``seq_pool_proj`` and ``mlp_head`` give the velocity: the action expert.

Its flow runs the other way from snapflow's (t = 0 noise, t = 1 data, velocity data - noise): snapflow's time is
1 - t and its velocity the negative of EVO1's. EVO1's time enters as a row, int(999 t), of a sinusoid table
(``time_pos_enc``), added to every block's normed input of its feed-forward; phi_s(s) is added to that row. Its noise
is uniform in [-1, 1], zero on the padded action width, and the velocity's input and output are masked there (and,
in training, past an episode's end). By default it integrates 32 Euler steps a chunk.
"""

from __future__ import annotations

import functools
from typing import Any

import torch
from torch import Tensor, nn

from snapflow.adapters.lerobot.base import ACTION, OBS_STATE, ChunkSampler, LeRobotFlowPolicy, split_timestep
from snapflow.flow.time_sampling import Beta22TimeSampler, TimeSampler
from snapflow.nn.time_embedding import TargetTimeEmbedding

#: EVO1's time table's rows: its time t is row int(999 t)
TIME_ROWS = 1000
#: what makes snapflow's float32 grid land on EVO1's own rows (1 - 2/3 rounds to a row below int(999 / 3) in float32
#: without it), while no row moves by more than a 1000th of itself
ROW_ROUNDING = 1e-3


def _time_table_with_target_time(encoder: nn.Module, target_time_embedding: nn.Module, rows: int) -> Tensor:
    """EVO1's ``time_pos_enc(rows)`` with phi_s(s) added to each row, s being the row's time in snapflow's direction
    (1 - row / 999): EVO1's own training forward and sampler read s = t."""
    table = type(encoder).forward(encoder, rows)
    s = 1 - torch.arange(rows, device=table.device, dtype=torch.float32) / (TIME_ROWS - 1)
    return table + target_time_embedding(s).to(table.dtype)[None]


class Evo1FlowPolicy(LeRobotFlowPolicy):
    """SnapFlow view of a LeRobot ``Evo1Policy``: InternVL3 and the state encoder are the frozen prefix; the action
    encoder, the transformer blocks and the output head the action expert."""

    policy_type = "evo1"
    steps_field = "num_inference_timesteps"
    minimum_lerobot = "0.6.1"
    # EVO1 tokenizes the task's text itself, inside the prefix: the batch carries no token ids to cut
    masks_prompt_padding = False
    export_refusal = (
        "EVO1 tokenizes the task's text (strings) with its InternVL tokenizer inside its prefix pass, on the host, so "
        "no graph of tensors from the batch to the chunk exists for torch.export to trace"
    )

    @property
    def head(self) -> nn.Module:
        """EVO1's action head: the state encoder (prefix) and the action expert."""
        return self.policy.model.action_head

    def new_target_time_embedding(self) -> TargetTimeEmbedding:
        return TargetTimeEmbedding(self.head.embed_dim)

    def install_target_time(self, model: nn.Module) -> None:
        # bound to phi_s itself, not to the policy that holds both: no module cycle
        encoder = model.action_head.time_pos_enc
        encoder.forward = functools.partial(_time_table_with_target_time, encoder, model.target_time_embedding)

    def expert_modules(self) -> list[nn.Module]:
        head = self.head
        projection = head.action_encoder if head.action_encoder is not None else head.single_action_proj
        return [projection, head.transformer_blocks, head.norm_out, head.seq_pool_proj, head.mlp_head]

    def action_targets(self, batch: dict[str, Tensor]) -> Tensor:
        """EVO1's padded chunk (``_prepare_actions``), zero where its mask is: the padded width, steps past an
        episode's end."""
        actions, mask = self.policy._prepare_actions(batch)
        return actions * mask.to(actions.dtype)

    def action_weights(self, batch: dict[str, Tensor]) -> Tensor:
        """EVO1's mask: its loss is the squared error's sum over the mask's entries by their count, the objective's
        weighted mean (:class:`snapflow.protocol.PaddedActions`). A batch without actions: the action width alone."""
        if ACTION in batch:
            return self.policy._prepare_actions(batch)[1].float()
        return self._width_mask(batch[OBS_STATE].shape[0])[:, None].float()

    @classmethod
    def training_time_sampler(cls, config: Any) -> TimeSampler:
        """EVO1's Beta(2, 2) clamped into [0.02, 0.98]: symmetric, so the same in snapflow's direction."""
        return Beta22TimeSampler(min_time=0.02, max_time=0.98)

    def _width_mask(self, batch_size: int) -> Tensor:
        """(B, max_action_dim): true on the robot's action width (EVO1's ``_prepare_inference_action_mask``)."""
        return self.policy._prepare_inference_action_mask(batch_size)

    def flow_noise(self, shape: tuple[int, ...], generator: Any = None, device: Any = None) -> Tensor:
        """EVO1's noise (:class:`snapflow.protocol.OwnNoise`): uniform in [-1, 1], zero on the padded action width."""
        return self._uniform_noise(shape, generator, device, torch.float32)

    def _uniform_noise(self, shape: tuple[int, ...], generator: Any, device: Any, dtype: torch.dtype) -> Tensor:
        noise = torch.rand(shape, generator=generator, device=device, dtype=dtype) * 2 - 1
        width = torch.arange(shape[-1], device=noise.device) < self.policy._env_action_dim
        return noise * width.to(dtype)

    def draw_noise(self, context: dict[str, Any], batch_size: int) -> Tensor:
        """EVO1's own draw (``get_action``): uniform in [-1, 1] in the prefix's dtype, after the prefix."""
        tokens = context["tokens"]
        return self._uniform_noise((batch_size, *self.action_shape), None, tokens.device, tokens.dtype)

    def model_inputs(self, batch: dict[str, Tensor]) -> tuple[Any, ...]:
        """What Evo1Policy's ``predict_action_chunk`` hands its VLM and action head: the tasks, the cameras and their
        mask, the padded state, the embodiments and the action width's mask. One task for a batch of several
        observations (a frame repeated, as bench repeats it) is every row's."""
        policy = self.policy
        images, image_masks = policy._collect_image_batches(batch)
        state, _ = policy._prepare_state(batch)
        size = state.shape[0]
        prompts = policy._normalize_task_batch(batch)
        prompts = prompts * size if len(prompts) == 1 else prompts
        return prompts, images, image_masks, state, policy._get_embodiment_ids(batch, size), self._width_mask(size)

    def encode(self, batch: dict[str, Tensor]) -> dict[str, Any]:
        """The prefix of :meth:`model_inputs`; a training batch's chunk is masked as EVO1's training forward masks
        it (``_prepare_actions``: past an episode's end too), its noisy input and its velocity alike."""
        context = super().encode(batch)
        if ACTION in batch:
            context["action_mask"] = self.action_weights(batch).to(context["action_mask"].dtype)
        return context

    def encode_inputs(
        self,
        prompts: list[str],
        images: list[Tensor],
        image_masks: Tensor,
        state: Tensor,
        embodiment_ids: Tensor,
        action_mask: Tensor,
    ) -> dict[str, Any]:
        policy = self.policy
        with self.prefix_pass(policy.model), policy._maybe_autocast():
            fused_tokens, context_mask = policy._compute_fused_tokens(prompts, images, image_masks)
            return self._prefix(fused_tokens, state, embodiment_ids, context_mask, action_mask)

    def _prefix(
        self, fused_tokens: Tensor, state: Tensor, embodiment_ids: Tensor, context_mask: Tensor | None, mask: Tensor
    ) -> dict[str, Any]:
        """The action head's part of the prefix (the state's token, the attention's padding mask) after the VLM's
        ``fused_tokens``, and the chunk's mask, as ``get_action`` prepares them."""
        head = self.head
        tokens, padding, embodiment_ids = head._prepare_context(fused_tokens, state, embodiment_ids, context_mask)
        size = tokens.shape[0]
        mask = head._expand_action_mask(mask, size, head.per_action_dim, tokens.device, tokens.dtype)
        return {
            "tokens": tokens.to(head.dtype),
            "padding": padding,
            "embodiment_id": embodiment_ids,
            "action_mask": mask,
        }

    def denoise(self, context: dict[str, Any], x_t: Tensor, timestep: Tensor) -> Tensor:
        """EVO1's ``predict_velocity`` at snapflow's time t, EVO1's row of 1 - t, with phi_s(s) added to the row."""
        with self.autocast(x_t.device.type):
            return self._velocity(context, x_t, *split_timestep(timestep)).to(x_t.dtype)

    def autocast(self, device_type: str) -> torch.autocast:
        """EVO1's precision (its ``_maybe_autocast``: bfloat16 on CUDA where ``use_amp``, else the caller's autocast,
        as ``lerobot-train``'s bfloat16 on the CPU), without autocast's weight cache: a weight cast in the objective's
        no-grad target pass, then reused from the cache by its gradient pass, would carry no gradient to the expert."""
        if self.policy._amp_enabled:
            return torch.autocast("cuda", dtype=torch.bfloat16, cache_enabled=False)
        enabled = torch.is_autocast_enabled(device_type)
        dtype = torch.get_autocast_dtype(device_type)
        return torch.autocast(device_type, dtype=dtype, enabled=enabled, cache_enabled=False)

    def _velocity(self, context: dict[str, Any], x_t: Tensor, t: Tensor, s: Tensor) -> Tensor:
        head, mask, embodiment = self.head, context["action_mask"], context["embodiment_id"]
        dtype, size = head.dtype, x_t.shape[0]
        # EVO1 trains and samples on whole rows of its table: a row between two never existed for it
        row = torch.floor((1 - t) * (TIME_ROWS - 1) + ROW_ROUNDING).long().clamp(0, TIME_ROWS - 1)
        time_emb = head.time_pos_enc.pe[0, row].to(dtype) + self.target_time_embedding(s).to(dtype)
        hidden = head._project_actions(x_t.to(mask.dtype) * mask, embodiment).to(dtype)
        for block in head.transformer_blocks:
            hidden = block(hidden, context["tokens"], time_emb, context["padding"])
        hidden = head.norm_out(hidden)
        pooled = head.seq_pool_proj(hidden.reshape(size, -1)) if head.horizon > 1 else hidden.squeeze(1)
        return -head.mlp_head(pooled, embodiment).view(x_t.shape) * mask

    def example_observation(self, device: torch.device) -> dict[str, Any]:
        """A batch-1 observation as EVO1's pre-processor hands it to the model: its cameras in [0, 1], its state
        padded to ``max_state_dim``, and the task as text (EVO1 tokenizes it itself)."""
        config = self.policy.config
        observation: dict[str, Any] = {
            key: torch.rand(1, *feature.shape, device=device) for key, feature in config.image_features.items()
        }
        observation[OBS_STATE] = torch.randn(1, config.max_state_dim, device=device)
        observation[config.task_field] = ["perform the task"]
        return observation

    def install_sampler(self, sample: ChunkSampler) -> None:
        def get_action(
            fused_tokens: Tensor,
            state: Tensor | None = None,
            embodiment_id: Tensor | None = None,
            action_mask: Tensor | None = None,
            context_mask: Tensor | None = None,
            inference_delay: int | None = None,
            prev_chunk_left_over: Tensor | None = None,
            execution_horizon: int | None = None,
            rtc_processor: Any = None,  # the base's sampling reads it from the model, as it reads every type's
        ) -> Tensor:
            with torch.no_grad():
                context = self._prefix(fused_tokens, state, embodiment_id, context_mask, action_mask)
                chunk = sample((), None, inference_delay, prev_chunk_left_over, execution_horizon, context=context)
            return chunk.reshape(chunk.shape[0], -1)

        self.head.get_action = get_action


__all__ = ["Evo1FlowPolicy"]
