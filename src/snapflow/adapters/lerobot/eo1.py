"""LeRobot's EO1Policy (EO-1) under SnapFlow (LeRobot >= 0.6.1).

EO-1 has no separate action expert: its chunk is a span of ``<|action_pad|>`` tokens at the end of a Qwen2.5-VL
chat, after the cameras, the state (one ``<|state_pad|>`` token, ``state_proj``) and the task. Sampling runs the
prompt up to that span through the backbone once, keeping its key/value cache (the prefix), then each Euler step
embeds the noisy chunk and the time into the span (``embed_suffix``), runs the same decoder layers over the span alone
against the cache and reads the velocity off ``action_out_proj``. So the expert is those decoder layers (which the
prefix shares), the action projections and the time MLP; the vision tower, the token embedding and ``state_proj`` run
in the prefix only. Distillation trains the expert with the prefix pass frozen (no graph): the layers it trains also
run the student's own prefix, whose cache is computed without gradient, as every prefix here is.

EO-1 follows openpi's flow (t = 1 noise, x_t = t noise + (1 - t) actions, velocity noise - actions, 10 Euler steps
from t = 1), snapflow's own; its time enters as pi0's does, ``action_time_mlp_out(SiLU(action_time_mlp_in([a,
sin(t)])))``, and phi_s(s) is added after ``action_time_mlp_in``. Its noise is a standard normal over the padded
width, its training times Beta(1.5, 1) * 0.999 + 0.001, and its loss weighs every entry of the padded chunk unless its
config leaves the padded width or the steps past an episode's end out (``supervise_padding_*``).
"""

from __future__ import annotations

import types
from typing import Any

import torch
from torch import Tensor, nn
from torch.nn import functional as F

from snapflow.adapters.lerobot.base import (
    ACTION,
    OBS_STATE,
    ChunkSampler,
    LeRobotFlowPolicy,
    modeling_module,
    split_timestep,
)
from snapflow.adapters.lerobot.prefix_cache import cache_for_one_pass, cache_tensors
from snapflow.errors import InvalidInputError
from snapflow.flow.time_sampling import TimeSampler
from snapflow.nn.time_embedding import TargetTimeEmbedding

#: the pre-processor's batch keys the prompt's tokens travel under, each (B, L), and the images' (one row a patch)
TOKEN_KEYS = ("input_ids", "attention_mask", "mm_token_type_ids")
IMAGE_KEYS = ("pixel_values", "image_grid_thw")


def _embed_suffix_with_target_time(self: nn.Module, timestep: Tensor, noisy_actions: Tensor) -> Tensor:
    """EO-1's ``EO1VisionFlowMatchingModel.embed_suffix`` with phi_s(s) added after ``action_time_mlp_in`` (s = t for
    LeRobot's own (B,) timestep)."""
    t, s = split_timestep(timestep)

    def project(noisy_actions: Tensor) -> Tensor:
        with self.flow_head_autocast_context():
            return self.action_in_proj(noisy_actions.to(dtype=self.action_in_proj.weight.dtype))

    action_embedding = self._apply_checkpoint(project, noisy_actions)
    config = self.config
    time_embedding = modeling_module(self).create_sinusoidal_pos_embedding(
        t, self.hidden_size, min_period=config.min_period, max_period=config.max_period, device=action_embedding.device
    )
    time_embedding = time_embedding.to(dtype=action_embedding.dtype)[:, None, :].expand_as(action_embedding)
    fusion_input = torch.cat([action_embedding, time_embedding], dim=2)

    def fuse(fusion_input: Tensor, s: Tensor) -> Tensor:
        with self.flow_head_autocast_context():
            fused = self.action_time_mlp_in(fusion_input.to(dtype=self.action_time_mlp_in.weight.dtype))
            fused = fused + self.target_time_embedding(s).to(fused.dtype)[:, None, :]
            return self.action_time_mlp_out(F.silu(fused))

    return self._apply_checkpoint(fuse, fusion_input, s)


def left_padded(tokens: dict[str, Tensor]) -> dict[str, Tensor]:
    """The prompt's token tensors (:data:`TOKEN_KEYS`) with each row's padding moved to its left, as EO-1's
    pre-processor pads a batch to sample: a training batch is right-padded, so each row's action span sits where its
    prompt ends, and the cache holds one prefix length. Positions count real tokens only, so nothing else changes."""
    mask = tokens["attention_mask"]
    padding = mask.shape[1] - mask.sum(dim=1, keepdim=True)
    if not bool(padding.any()) or bool(mask[:, -1].all()):  # no padding, or on the left already
        return tokens
    index = (torch.arange(mask.shape[1], device=mask.device)[None] - padding) % mask.shape[1]
    return {key: value.gather(1, index) for key, value in tokens.items()}


class EO1FlowPolicy(LeRobotFlowPolicy):
    """SnapFlow view of a LeRobot ``EO1Policy``: the vision tower, the token embedding and ``state_proj`` are the
    prefix; the Qwen2.5 decoder layers over the action span, the action projections and the time MLP the expert."""

    policy_type = "eo1"
    steps_field = "num_denoise_steps"
    minimum_lerobot = "0.6.1"
    # the prompt is Qwen's chat left-padded to sample: the batch carries no language tokens to cut
    masks_prompt_padding = False
    export_refusal = (
        "Qwen2.5-VL's multimodal rotary positions walk the prompt's tokens on the host (get_rope_index: .tolist()), "
        "and EO-1 finds its action span there too, which torch.export cannot trace"
    )

    @property
    def decoder(self) -> nn.Module:
        """The Qwen2.5 language model: its embedding runs in the prefix, its layers in both passes."""
        return self.policy.model.vlm_backbone.model.language_model

    def new_target_time_embedding(self) -> TargetTimeEmbedding:
        model = self.policy.model
        return TargetTimeEmbedding(
            model.action_time_mlp_in.out_features,
            min_period=model.config.min_period,
            max_period=model.config.max_period,
        )

    def install_target_time(self, model: nn.Module) -> None:
        model.embed_suffix = types.MethodType(_embed_suffix_with_target_time, model)

    def expert_modules(self) -> list[nn.Module]:
        model, decoder = self.policy.model, self.decoder
        projections = [model.action_in_proj, model.action_time_mlp_in, model.action_time_mlp_out, model.action_out_proj]
        return [decoder.layers, decoder.norm, *projections]

    @classmethod
    def training_time_sampler(cls, config: Any) -> TimeSampler:
        """EO-1's Beta(alpha, 1) * scale + offset, which is snapflow's Beta(alpha, 1) from ``offset`` where the two
        add up to 1 (0.999 and 0.001 by default)."""
        scale, offset = config.time_sampling_scale, config.time_sampling_offset
        if abs(scale + offset - 1) > 1e-9:
            raise InvalidInputError(
                f"this eo1 samples times Beta * {scale} + {offset}, which does not reach t = 1; snapflow samples "
                "Beta(a, 1) stretched over [offset, 1] only"
            )
        sampler = super().training_time_sampler(config)
        return type(sampler)(concentration=sampler.concentration, min_time=offset)

    def action_targets(self, batch: dict[str, Tensor]) -> Tensor:
        """The chunk padded to ``max_action_dim`` with zeros, as EO-1's ``forward`` pads it."""
        return self.policy.prepare_action(batch[ACTION])

    def action_weights(self, batch: dict[str, Tensor]) -> Tensor | None:
        """What EO-1's loss weighs: every entry by default; 0 past the robot's action width where its config says
        ``supervise_padding_action_dims=False``, and past an episode's end (``action_is_pad``) where it says
        ``supervise_padding_actions=False`` (:class:`snapflow.protocol.PaddedActions`)."""
        config, weights = self.policy.config, None
        if not config.supervise_padding_action_dims:
            width = self.action_shape[1]
            weights = torch.arange(width, device=batch[OBS_STATE].device) < config.action_feature.shape[0]
        if not config.supervise_padding_actions and "action_is_pad" in batch:
            kept = ~batch["action_is_pad"].bool()[..., None]
            weights = kept if weights is None else kept & weights
        return weights

    def model_inputs(self, batch: dict[str, Tensor]) -> tuple[Any, ...]:
        """What EO1Policy's ``predict_action_chunk`` hands its model's ``sample_actions``: the prompt's tokens, the
        images' patches and grids, the padded state and the two placeholder ids. Patches under a leading row axis
        (:meth:`example_observation`) are flattened, as the pre-processor lays them out."""
        images = [batch[key].flatten(0, 1) if batch[key].ndim == 3 else batch[key] for key in IMAGE_KEYS]
        tokens = [batch[key] for key in TOKEN_KEYS]
        state = self.policy.prepare_state(batch[OBS_STATE])
        return (*tokens, *images, state, batch["state_token_id"], batch["action_token_id"])

    def encode(self, batch: dict[str, Tensor]) -> dict[str, Any]:
        """The prefix of :meth:`model_inputs`; in a training batch whose config leaves the steps past an episode's end
        out of its loss, those action tokens are masked out of the attention, as EO-1's ``forward`` masks them."""
        context = super().encode(batch)
        if ACTION in batch and not self.policy.config.supervise_padding_actions and "action_is_pad" in batch:
            mask, chunk = context["attention_mask"], self.action_shape[0]
            kept = (~batch["action_is_pad"].bool()).to(mask.dtype)
            context["attention_mask"] = torch.cat([mask[:, :-chunk], mask[:, -chunk:] * kept], dim=1)
        return context

    def encode_inputs(
        self,
        input_ids: Tensor,
        attention_mask: Tensor,
        mm_token_type_ids: Tensor,
        pixel_values: Tensor,
        image_grid_thw: Tensor,
        state: Tensor,
        state_token_id: int,
        action_token_id: int,
    ) -> dict[str, Any]:
        """EO-1's ``sample_actions`` up to its loop: the prompt, its state scattered in, through the backbone up to the
        action span, keeping the cache, and the span's attention mask and rotary positions (rows first)."""
        model = self.policy.model
        tokens = left_padded(dict(zip(TOKEN_KEYS, (input_ids, attention_mask, mm_token_type_ids), strict=True)))
        input_ids, attention_mask, mm_token_type_ids = (tokens[key] for key in TOKEN_KEYS)
        ids = {"state_token_id": state_token_id, "action_token_id": action_token_id}
        start = self._action_span_start(input_ids, action_token_id)
        backbone = model.vlm_backbone.model
        with self.prefix_pass(model):
            embeddings = model.embed_prefix(input_ids, states=state, **ids)
            positions, _ = backbone.get_rope_index(
                input_ids,
                image_grid_thw=image_grid_thw,
                attention_mask=attention_mask,
                mm_token_type_ids=mm_token_type_ids,
            )
            outputs = backbone(
                input_ids=input_ids[:, :start],
                attention_mask=attention_mask[:, :start],
                position_ids=positions[..., :start],
                inputs_embeds=embeddings[:, :start],
                pixel_values=pixel_values,
                image_grid_thw=image_grid_thw,
                mm_token_type_ids=mm_token_type_ids[:, :start],
                use_cache=True,
                return_dict=True,
            )
        end = start + self.action_shape[0]
        return {
            "cache": cache_tensors(outputs.past_key_values),
            "attention_mask": attention_mask[:, :end],
            "position_ids": positions[..., start:end].transpose(0, 1),  # (3, B, chunk) -> rows first, to select
        }

    def _action_span_start(self, input_ids: Tensor, action_token_id: int) -> int:
        """Where every row's chunk of action tokens starts, checked as EO-1's ``sample_actions`` checks it."""
        chunk, span = self.action_shape[0], input_ids == action_token_id
        start = int(span[0].to(torch.int64).argmax())
        if not (bool((span.sum(dim=1) == chunk).all()) and bool(span[:, start : start + chunk].all())):
            raise InvalidInputError(
                f"each row of an eo1 batch holds one contiguous span of {chunk} action tokens at one place: "
                "give the batch as EO-1's own pre-processor makes it"
            )
        return start

    def denoise(self, context: dict[str, Any], x_t: Tensor, timestep: Tensor) -> Tensor:
        """One step of EO-1's loop (``denoise_fn``): the noisy chunk and the time embedded into the action span, the
        decoder over the span against the prefix's cache, ``action_out_proj`` on its hidden states. Under the caller's
        autocast without its weight cache: a weight cast in the objective's no-grad target pass, reused by its gradient
        pass, would carry no gradient to the expert."""
        model = self.policy.model
        device = x_t.device.type
        enabled, dtype = torch.is_autocast_enabled(device), torch.get_autocast_dtype(device)
        with torch.autocast(device, dtype=dtype, enabled=enabled, cache_enabled=False):
            suffix = model.embed_suffix(timestep, x_t).to(model.get_input_embeddings().weight.dtype)
            outputs = model.vlm_backbone.model(
                attention_mask=context["attention_mask"],
                past_key_values=cache_for_one_pass(context["cache"]),
                inputs_embeds=suffix,
                position_ids=context["position_ids"].transpose(0, 1),
                use_cache=True,
                return_dict=True,
            )
            with model.flow_head_autocast_context():
                hidden = outputs.last_hidden_state.to(dtype=model.action_out_proj.dtype)
                velocity = model.action_out_proj(hidden)
        return velocity.reshape(x_t.shape).to(x_t.dtype)

    def draw_noise(self, context: dict[str, Any], batch_size: int) -> Tensor:
        """EO-1's own ``sample_noise`` after the prefix, in the flow head's dtype, so a seeded chunk is EO-1's."""
        model = self.policy.model
        noise = model.sample_noise((batch_size, *self.action_shape), context["attention_mask"].device)
        return noise.to(dtype=model.action_in_proj.weight.dtype)

    def run_in(self, dtype: torch.dtype) -> None:
        """EO-1's own mixed precision (its config's ``dtype``): the backbone in bfloat16, the flow head in float32."""
        if dtype != torch.bfloat16:
            super().run_in(dtype)
        self.policy.model.vlm_backbone.to(dtype)

    def example_observation(self, device: torch.device) -> dict[str, Any]:
        """EO-1's own pre-processor's batch of one random frame (unit statistics), its patches and grids under a
        leading row axis, so that a batch of this frame repeated is its rows repeated (:meth:`model_inputs`)."""
        from lerobot.policies.eo1.processor_eo1 import make_eo1_pre_post_processors

        config = self.policy.config
        widths = {OBS_STATE: config.robot_state_feature.shape, ACTION: config.action_feature.shape}
        stats = {key: {"mean": torch.zeros(shape), "std": torch.ones(shape)} for key, shape in widths.items()}
        preprocessor, _ = make_eo1_pre_post_processors(config, dataset_stats=stats)
        frame = {key: torch.rand(1, *feature.shape) for key, feature in config.image_features.items()}
        batch = preprocessor({**frame, OBS_STATE: torch.randn(1, *widths[OBS_STATE]), "task": ["pick the red cube"]})
        batch = {**batch, **{key: batch[key][None] for key in IMAGE_KEYS}}
        kept = {key: value.to(device) for key, value in batch.items() if torch.is_tensor(value)}
        return {**kept, "state_token_id": batch["state_token_id"], "action_token_id": batch["action_token_id"]}

    def install_sampler(self, sample: ChunkSampler) -> None:
        def sample_actions(
            model: nn.Module,
            input_ids: Tensor,
            attention_mask: Tensor,
            pixel_values: Tensor,
            image_grid_thw: Tensor,
            mm_token_type_ids: Tensor,
            states: Tensor,
            *,
            state_token_id: int,
            action_token_id: int,
            **_: Any,  # the rest of the batch, which EO-1's predict_action_chunk hands on too
        ) -> Tensor:
            tokens = (input_ids, attention_mask, mm_token_type_ids, pixel_values, image_grid_thw)
            return sample((*tokens, states, state_token_id, action_token_id))

        self.policy.model.sample_actions = types.MethodType(sample_actions, self.policy.model)


__all__ = ["EO1FlowPolicy", "left_padded"]
