"""LeRobot's SmolVLAPolicy under SnapFlow (LeRobot 0.4.4 and newer).

SmolVLA fuses time into every action token: ``action_time_mlp_out(SiLU(action_time_mlp_in([a, sin(t)])))``;
phi_s(s) is added to the output of ``action_time_mlp_in``, before the SiLU. Each token may take its own t and s
(real-time chunking trained in: the known prefix at time 0). The state is a prefix token, so it
goes through the frozen VLM with the images and the instruction.
"""

from __future__ import annotations

import inspect
from collections.abc import Callable
from pathlib import Path
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
from snapflow.adapters.lerobot.smolvlm import smolvla_config
from snapflow.adapters.lerobot_config import SmolVLMSize


def per_action(embed: Callable[[Tensor], Tensor], times: Tensor, chunk: int) -> Tensor:
    """``embed`` (of (N,) times) of each action's time: (B, chunk, width) from times (B,) or (B, chunk)."""
    if times.ndim == 1:
        return embed(times)[:, None, :].expand(-1, chunk, -1)
    return embed(times.reshape(-1)).reshape(*times.shape, -1)


def _embed_suffix_with_target_time(
    self: nn.Module, noisy_actions: Tensor, timestep: Tensor
) -> tuple[Tensor, Tensor, Tensor]:
    """SmolVLA's ``VLAFlowMatching.embed_suffix`` with phi_s(s) added after ``action_time_mlp_in``; ``timestep`` (B,)
    as LeRobot's, (B, 2) as [t, s] a row, or (B, 2, chunk) as [t, s] an action."""
    t, s = split_timestep(timestep)
    action_embedding = self.action_in_proj(noisy_actions)
    batch, chunk, width = action_embedding.shape
    sinusoid = modeling_module(self).create_sinusoidal_pos_embedding
    time_embedding = per_action(
        lambda times: sinusoid(times, width, self.config.min_period, self.config.max_period, device=times.device),
        t,
        chunk,
    )
    fused = self.action_time_mlp_in(torch.cat([action_embedding, time_embedding.to(action_embedding.dtype)], dim=2))
    fused = fused + per_action(self.target_time_embedding, s, chunk).to(fused.dtype)
    embeddings = self.action_time_mlp_out(F.silu(fused))
    pad_masks = torch.ones(batch, chunk, dtype=torch.bool, device=embeddings.device)
    # each action token opens its own attention block: actions attend causally among themselves and to the prefix
    att_masks = torch.ones(batch, chunk, dtype=embeddings.dtype, device=embeddings.device)
    return embeddings, pad_masks, att_masks


def _patch_positions(mask: Tensor, patches_per_side: int, dtype: torch.dtype) -> Tensor:
    """The position ids SmolVLM's vision embeddings give a batch's patches under ``mask`` (batch, rows, columns):
    each real patch's fractional row and column bucketed onto the ``patches_per_side`` grid, 0 on padding. The same
    ids as transformers' ``SmolVLMVisionEmbeddings``, which writes them through a boolean-mask index (a host
    synchronisation, so no CUDA graph can hold it); here a ``torch.where``."""
    rows, columns = mask[:, :, 0].sum(dim=1), mask[:, 0, :].sum(dim=1)
    boundaries = torch.arange(1 / patches_per_side, 1.0, 1 / patches_per_side, device=mask.device)

    def buckets(count: Tensor, size: int) -> Tensor:
        coordinates = torch.arange(size, device=mask.device, dtype=torch.float32)[None, :] / count[:, None]
        return torch.bucketize(coordinates.clamp(max=1.0 - 1e-6).to(dtype), boundaries, right=True)

    grid = buckets(rows, mask.shape[1])[:, :, None] * patches_per_side + buckets(columns, mask.shape[2])[:, None, :]
    return torch.where(mask, grid, 0).flatten(1)


def _capturable_embeddings_forward(embeddings: nn.Module) -> Any:
    """``embeddings.forward`` (a ``SmolVLMVisionEmbeddings``) with its position ids from :func:`_patch_positions`."""

    def forward(pixel_values: Tensor, patch_attention_mask: Tensor) -> Tensor:
        patches = embeddings.patch_embedding(pixel_values).flatten(2).transpose(1, 2)
        positions = _patch_positions(patch_attention_mask, embeddings.num_patches_per_side, pixel_values.dtype)
        return patches + embeddings.position_embedding(positions)

    return forward


class SmolVLAFlowPolicy(PrefixCacheFlowPolicy):
    """SnapFlow view of a LeRobot ``SmolVLAPolicy``."""

    policy_type = "smolvla"
    steps_field = "num_steps"
    time_fusion_layer = "action_time_mlp_in"
    embed_suffix_with_target_time = staticmethod(_embed_suffix_with_target_time)

    @classmethod
    def scratch_config(
        cls, vlm: Path, input_features: dict[str, Any], output_features: dict[str, Any], size: SmolVLMSize, **sizes: Any
    ) -> Any:
        return smolvla_config(vlm, input_features, output_features, size, **sizes)

    def expert_modules(self) -> list[nn.Module]:
        # the state projection feeds the VLM prefix, so it stays frozen with the VLM
        model = self.policy.model
        return [
            model.vlm_with_expert.lm_expert,
            model.action_in_proj,
            model.action_out_proj,
            model.action_time_mlp_in,
            model.action_time_mlp_out,
        ]

    def velocity_per_action(self, x_t: Tensor, t: Tensor, s: Tensor, context: dict[str, Any]) -> Tensor:
        """The velocity with a time and target time per action, (B, chunk) each: SmolVLA embeds time per action
        token, so a known prefix rides at time 0 (:class:`~snapflow.protocol.PerActionTimes`)."""
        return self.velocity(x_t, t, s, context)

    def loss_cuts_padded_width(self) -> bool:
        """From LeRobot 0.5.1 on; before, SmolVLA's loss weighed the whole padded width (it cut at ``max_action_dim``)."""
        from importlib.metadata import version

        from packaging.version import Version

        return Version(version("lerobot")) >= Version("0.5.1")

    def model_inputs(self, batch: dict[str, Tensor]) -> tuple[Any, ...]:
        images, image_masks = self.policy.prepare_images(batch)
        return (
            images,
            image_masks,
            batch[OBS_LANGUAGE_TOKENS],
            batch[OBS_LANGUAGE_ATTENTION_MASK],
            self.policy.prepare_state(batch),
        )

    def without_host_syncs(self) -> None:
        """Make the prefix pass capturable in one CUDA graph (``deploy``): SmolVLM's vision embeddings compute the
        same position ids without a boolean-mask index (:func:`_patch_positions`), on this instance only. From
        transformers 5 on, whose embeddings this reproduces; older releases bucket the patches otherwise (one image
        at a time, sized by ``.item()``) and keep their own."""
        import transformers
        from packaging.version import Version

        if Version(transformers.__version__) < Version("5"):
            return
        vision = self.policy.model.vlm_with_expert.get_vlm_model().vision_model
        vision.embeddings.forward = _capturable_embeddings_forward(vision.embeddings)

    def encode_inputs(
        self, images: list[Tensor], image_masks: list[Tensor], tokens: Tensor, token_masks: Tensor, state: Tensor
    ) -> dict[str, Any]:
        model = self.policy.model
        vlm = model.vlm_with_expert
        # LeRobot 0.4.4 fills its dict cache only when asked; newer versions return a DynamicCache
        extra = {"fill_kv_cache": True} if "fill_kv_cache" in inspect.signature(vlm.forward).parameters else {}
        with self.prefix_pass(vlm.vlm):  # the state projection is in the prefix: frozen with it, or trained
            prefix, pad_masks, att_masks = model.embed_prefix(images, image_masks, tokens, token_masks, state=state)
            _, cache = vlm.forward(
                attention_mask=modeling_module(model).make_att_2d_masks(pad_masks, att_masks),
                position_ids=torch.cumsum(pad_masks, dim=1) - 1,
                past_key_values=None,
                inputs_embeds=[prefix, None],
                use_cache=True,
                **extra,
            )
        return {"cache": cache_tensors(cache), "prefix_pad_masks": pad_masks}

    def denoise(self, context: dict[str, Any], x_t: Tensor, timestep: Tensor) -> Tensor:
        return self.policy.model.denoise_step(
            context["prefix_pad_masks"], cache_for_one_pass(context["cache"]), x_t, timestep
        )


__all__ = ["SmolVLAFlowPolicy"]
