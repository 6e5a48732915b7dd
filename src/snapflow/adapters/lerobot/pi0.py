"""LeRobot's PI0Policy and PI05Policy under SnapFlow (LeRobot >= 0.5, stock transformers).

pi0 fuses time into every action token, ``action_time_mlp_out(SiLU(action_time_mlp_in([a, sin(t)])))``, with
the state as the first suffix token; phi_s(s) is added after ``action_time_mlp_in``. pi0.5 carries no time in its
action tokens: ``SiLU(time_mlp_out(SiLU(time_mlp_in(sin(t)))))`` is the adaptive-RMSNorm condition of every
expert block; phi_s(s) is added after ``time_mlp_in``. Both fill PaliGemma's cache once per batch, then run only
the Gemma action expert per pass.
"""

from __future__ import annotations

from typing import Any

import torch
from torch import Tensor, nn
from torch.nn import functional as F

from snapflow.adapters.lerobot.base import (
    OBS_LANGUAGE_ATTENTION_MASK,
    OBS_LANGUAGE_TOKENS,
    modeling_module,
    split_timestep,
)
from snapflow.adapters.lerobot.prefix_cache import PrefixCacheFlowPolicy, cache_for_one_pass, cache_tensors


def _suffix_attention_masks(self: nn.Module, state_tokens: int, like: Tensor) -> Tensor:
    """The pi0 family's suffix layout: the state token (pi0) opens a block, the actions open one more and
    attend to each other bidirectionally."""
    pattern = [1] * state_tokens + [1] + [0] * (self.config.chunk_size - 1)
    return torch.tensor(pattern, dtype=like.dtype, device=like.device)[None, :].expand(like.shape[0], len(pattern))


def _pi0_embed_suffix_with_target_time(
    self: nn.Module, state: Tensor, noisy_actions: Tensor, timestep: Tensor
) -> tuple[Tensor, Tensor, Tensor, None]:
    """pi0's ``PI0Pytorch.embed_suffix`` with phi_s(s) added after ``action_time_mlp_in``."""
    t, s = split_timestep(timestep)
    if self.state_proj.weight.dtype == torch.float32:
        state = state.to(torch.float32)
    state_embedding = self._apply_checkpoint(self.state_proj, state)[:, None, :]
    time_embedding = (
        modeling_module(self)
        .create_sinusoidal_pos_embedding(
            t,
            self.action_in_proj.out_features,
            min_period=self.config.min_period,
            max_period=self.config.max_period,
            device=t.device,
        )
        .type(t.dtype)
    )
    action_embedding = self._apply_checkpoint(self.action_in_proj, noisy_actions)
    fusion_input = torch.cat([action_embedding, time_embedding[:, None, :].expand_as(action_embedding)], dim=2)

    def fuse(fusion_input: Tensor, target: Tensor) -> Tensor:
        fused = self.action_time_mlp_in(fusion_input) + target.to(fusion_input.dtype)[:, None, :]
        return self.action_time_mlp_out(F.silu(fused))

    action_time_embedding = self._apply_checkpoint(fuse, fusion_input, self.target_time_embedding(s))
    embeddings = torch.cat([state_embedding, action_time_embedding], dim=1)
    pad_masks = torch.ones(embeddings.shape[:2], dtype=torch.bool, device=t.device)
    return embeddings, pad_masks, _suffix_attention_masks(self, 1, embeddings), None


def _pi05_embed_suffix_with_target_time(
    self: nn.Module, noisy_actions: Tensor, timestep: Tensor
) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """pi0.5's ``PI05Pytorch.embed_suffix`` with phi_s(s) added after ``time_mlp_in`` (the adaRMS condition)."""
    t, s = split_timestep(timestep)
    time_embedding = (
        modeling_module(self)
        .create_sinusoidal_pos_embedding(
            t,
            self.action_in_proj.out_features,
            min_period=self.config.min_period,
            max_period=self.config.max_period,
            device=t.device,
        )
        .type(t.dtype)
    )
    action_embedding = self._apply_checkpoint(self.action_in_proj, noisy_actions)

    def condition(time_embedding: Tensor, target: Tensor) -> Tensor:
        hidden = F.silu(self.time_mlp_in(time_embedding) + target.to(time_embedding.dtype))
        return F.silu(self.time_mlp_out(hidden))

    adarms_condition = self._apply_checkpoint(condition, time_embedding, self.target_time_embedding(s))
    pad_masks = torch.ones(action_embedding.shape[:2], dtype=torch.bool, device=t.device)
    return action_embedding, pad_masks, _suffix_attention_masks(self, 0, action_embedding), adarms_condition


class PI0FlowPolicy(PrefixCacheFlowPolicy):
    """SnapFlow view of a LeRobot ``PI0Policy``."""

    policy_type = "pi0"
    steps_field = "num_inference_steps"
    time_fusion_layer = "action_time_mlp_in"
    embed_suffix_with_target_time = staticmethod(_pi0_embed_suffix_with_target_time)
    minimum_lerobot = "0.5"  # 0.4.4's pi0 needs a transformers fork and has another internal layout

    def expert_modules(self) -> list[nn.Module]:
        model = self.policy.model
        return [
            model.paligemma_with_expert.gemma_expert.model,
            model.action_in_proj,
            model.action_out_proj,
            model.state_proj,
            model.action_time_mlp_in,
            model.action_time_mlp_out,
        ]

    def model_inputs(self, batch: dict[str, Tensor]) -> tuple[Any, ...]:
        images, image_masks = self.policy._preprocess_images(batch)
        return (
            images,
            image_masks,
            batch[OBS_LANGUAGE_TOKENS],
            batch[OBS_LANGUAGE_ATTENTION_MASK],
            self.policy.prepare_state(batch),
        )

    def encode_inputs(
        self, images: list[Tensor], image_masks: list[Tensor], tokens: Tensor, token_masks: Tensor, state: Tensor
    ) -> dict[str, Any]:
        # pi0 re-embeds the state as a suffix token in every denoising step
        return {**self.prefix_cache(images, image_masks, tokens, token_masks), "state": state}

    def prefix_cache(
        self, images: list[Tensor], image_masks: list[Tensor], tokens: Tensor, token_masks: Tensor
    ) -> dict[str, Any]:
        """PaliGemma over images and prompt once, as LeRobot's ``sample_actions`` runs it."""
        model = self.policy.model
        helpers = modeling_module(model)
        paligemma = model.paligemma_with_expert.paligemma
        paligemma.model.language_model.config._attn_implementation = (
            "eager"  # as LeRobot's sampler sets it for 4-D masks
        )
        with self.prefix_pass(paligemma):
            prefix, pad_masks, att_masks = model.embed_prefix(images, image_masks, tokens, token_masks)
            _, cache = model.paligemma_with_expert.forward(
                attention_mask=helpers.prepare_attention_masks_4d(helpers.make_att_2d_masks(pad_masks, att_masks)),
                position_ids=torch.cumsum(pad_masks, dim=1) - 1,
                past_key_values=None,
                inputs_embeds=[prefix, None],
                use_cache=True,
            )
        return {"cache": cache_tensors(cache), "prefix_pad_masks": pad_masks}

    def denoise(self, context: dict[str, Any], x_t: Tensor, timestep: Tensor) -> Tensor:
        return self.policy.model.denoise_step(
            context["state"], context["prefix_pad_masks"], cache_for_one_pass(context["cache"]), x_t, timestep
        )

    def run_in(self, dtype: torch.dtype) -> None:
        """LeRobot's own mixed precision, bfloat16 only: the VLM and expert in bfloat16, the layers it keeps in
        float32 kept."""
        if dtype != torch.bfloat16:
            super().run_in(dtype)
        self.policy.model.paligemma_with_expert.to_bfloat16_for_selected_params("bfloat16")

    def run_vision_in(self, dtype: torch.dtype) -> None:
        """Run the vision tower and its projector in ``dtype``. LeRobot keeps them in float32 under bfloat16 (its
        ``embed_image`` casts every image to float32); here the images are cast to ``dtype`` as they enter the
        tower, and LeRobot casts the features back as before. A second call for the same dtype changes nothing."""
        paligemma = self.policy.model.paligemma_with_expert.paligemma.model
        if "get_image_features" in vars(paligemma) and next(paligemma.vision_tower.parameters()).dtype == dtype:
            return
        paligemma.vision_tower.to(dtype)
        paligemma.multi_modal_projector.to(dtype)
        image_features = type(paligemma).get_image_features.__get__(paligemma)

        def get_image_features(pixel_values: Tensor, *args: Any, **kwargs: Any) -> Any:
            return image_features(pixel_values.to(dtype), *args, **kwargs)

        paligemma.get_image_features = get_image_features


class PI05FlowPolicy(PI0FlowPolicy):
    """SnapFlow view of a LeRobot ``PI05Policy``; its state reaches the model as tokens of the prompt."""

    policy_type = "pi05"
    time_fusion_layer = "time_mlp_in"
    embed_suffix_with_target_time = staticmethod(_pi05_embed_suffix_with_target_time)

    def expert_modules(self) -> list[nn.Module]:
        model = self.policy.model
        return [
            model.paligemma_with_expert.gemma_expert.model,
            model.action_in_proj,
            model.action_out_proj,
            model.time_mlp_in,
            model.time_mlp_out,
        ]

    def model_inputs(self, batch: dict[str, Tensor]) -> tuple[Any, ...]:
        images, image_masks = self.policy._preprocess_images(batch)
        return images, image_masks, batch[OBS_LANGUAGE_TOKENS], batch[OBS_LANGUAGE_ATTENTION_MASK]

    def encode_inputs(
        self, images: list[Tensor], image_masks: list[Tensor], tokens: Tensor, token_masks: Tensor
    ) -> dict[str, Any]:
        return self.prefix_cache(images, image_masks, tokens, token_masks)

    def denoise(self, context: dict[str, Any], x_t: Tensor, timestep: Tensor) -> Tensor:
        return self.policy.model.denoise_step(
            context["prefix_pad_masks"], cache_for_one_pass(context["cache"]), x_t, timestep
        )


__all__ = ["PI0FlowPolicy", "PI05FlowPolicy"]
