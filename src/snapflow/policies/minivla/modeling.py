"""MiniVLA: a compact vision-language-action flow-matching policy with pi0.5's structure.

* Prefix encoder (the "VLM"): instruction tokens, one state token and optional image tokens (patches, or
  keypoints of a small ConvNet a camera: :mod:`snapflow.policies.minivla.vision`) through bidirectional
  transformer layers. ``encode`` runs it once per observation and caches each layer's keys
  and values, which is all the action expert needs: prefix cost and denoising cost are separate.
* Action expert: one token per action of the chunk; layer l attends to [prefix keys/values of layer l ;
  its own tokens] and is conditioned on time through adaptive RMSNorm (scale, shift, gate), as pi0.5 is.

It implements :class:`snapflow.protocol.TimeEmbeddingModel`; wrap it in :class:`snapflow.nn.SnapFlowPolicy`.
"""

from __future__ import annotations

import torch
from torch import Tensor, nn
from torch.nn import functional as F

from snapflow.nn.time_embedding import sinusoidal_features
from snapflow.policies.minivla.configuration import MiniVLAConfig
from snapflow.policies.minivla.vision import ConvEncoder


class RMSNorm(nn.Module):
    def __init__(self, width: int, affine: bool = True, eps: float = 1e-6) -> None:
        super().__init__()
        self.eps = eps
        self.weight = nn.Parameter(torch.ones(width)) if affine else None

    def forward(self, x: Tensor) -> Tensor:
        x = x * torch.rsqrt(x.pow(2).mean(-1, keepdim=True) + self.eps)
        return x * self.weight if self.weight is not None else x


def _mlp(width: int, ratio: int) -> nn.Sequential:
    return nn.Sequential(nn.Linear(width, ratio * width), nn.GELU(approximate="tanh"), nn.Linear(ratio * width, width))


class _Attention(nn.Module):
    """Multi-head projections; keys and values may be prefixed with cached ones."""

    def __init__(self, width: int, num_heads: int, head_dim: int) -> None:
        super().__init__()
        self.num_heads, self.head_dim = num_heads, head_dim
        self.qkv = nn.Linear(width, 3 * num_heads * head_dim)
        self.out = nn.Linear(num_heads * head_dim, width)

    def project(self, x: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        batch, length, _ = x.shape
        q, k, v = self.qkv(x).view(batch, length, 3, self.num_heads, self.head_dim).permute(2, 0, 3, 1, 4)
        return q, k, v

    def attend(self, q: Tensor, k: Tensor, v: Tensor, key_mask: Tensor) -> Tensor:
        output = F.scaled_dot_product_attention(q, k, v, attn_mask=key_mask[:, None, None, :])
        batch, _, length, _ = output.shape
        return self.out(output.transpose(1, 2).reshape(batch, length, self.num_heads * self.head_dim))


class PrefixLayer(nn.Module):
    def __init__(self, config: MiniVLAConfig) -> None:
        super().__init__()
        self.attention_norm = RMSNorm(config.prefix_width)
        self.attention = _Attention(config.prefix_width, config.num_heads, config.head_dim)
        self.mlp_norm = RMSNorm(config.prefix_width)
        self.mlp = _mlp(config.prefix_width, config.mlp_ratio)

    def forward(self, x: Tensor, mask: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        q, k, v = self.attention.project(self.attention_norm(x))
        x = x + self.attention.attend(q, k, v, mask)
        return x + self.mlp(self.mlp_norm(x)), k, v


def _per_action(modulation: Tensor) -> Tensor:
    """A modulation (B, width) shared by the chunk's actions as (B, 1, width); (B, chunk, width), each action's own,
    as it is."""
    return modulation[:, None, :] if modulation.ndim == 2 else modulation


class ExpertLayer(nn.Module):
    def __init__(self, config: MiniVLAConfig) -> None:
        super().__init__()
        width = config.expert_width
        self.norm = RMSNorm(width, affine=False)
        self.attention = _Attention(width, config.num_heads, config.head_dim)
        self.mlp = _mlp(width, config.mlp_ratio)
        # adaptive RMSNorm: time -> (scale, shift, gate) for attention and MLP; zero gates make a block the identity at init
        self.modulation = nn.Linear(width, 6 * width)
        nn.init.zeros_(self.modulation.weight)
        nn.init.zeros_(self.modulation.bias)

    def forward(self, x: Tensor, condition: Tensor, prefix_k: Tensor, prefix_v: Tensor, prefix_mask: Tensor) -> Tensor:
        scale_a, shift_a, gate_a, scale_m, shift_m, gate_m = _per_action(self.modulation(condition)).chunk(6, dim=-1)
        q, k, v = self.attention.project(self.norm(x) * (1 + scale_a) + shift_a)
        keys, values = torch.cat([prefix_k, k], dim=2), torch.cat([prefix_v, v], dim=2)
        mask = torch.cat([prefix_mask, prefix_mask.new_ones(x.shape[0], x.shape[1])], dim=1)
        x = x + gate_a * self.attention.attend(q, keys, values, mask)
        return x + gate_m * self.mlp(self.norm(x) * (1 + scale_m) + shift_m)


def camera_keys(config: MiniVLAConfig) -> list[str]:
    """The observation keys of the cameras' frames: ``image`` (the main camera), then ``image.<camera>``."""
    return ["image", *(f"image.{name}" for name in config.extra_cameras)]


class MiniVLA(nn.Module):
    """Observation dict in (see :meth:`encode`), velocity of the noisy action chunk out.

    Its time enters each action through that action's adaptive norm, so a time embedding may be one a chunk,
    (B, width), or one an action, (B, chunk, width): ``per_action_times`` declares it to
    :class:`~snapflow.nn.SnapFlowPolicy` (real-time chunking trained in, :mod:`snapflow.flow.known_prefix`).
    """

    per_action_times = True

    def __init__(self, config: MiniVLAConfig) -> None:
        super().__init__()
        self.config = config
        self.time_embedding_dim = config.expert_width
        self.token_embedding = nn.Embedding(config.vocab_size, config.prefix_width, padding_idx=0)
        self.state_projection = nn.Linear(config.state_dim, config.prefix_width)
        patches = config.use_image and config.image_encoder == "patch"
        self.patch_embedding = (
            nn.Conv2d(3, config.prefix_width, config.patch_size, stride=config.patch_size) if patches else None
        )
        self.camera_encoders = nn.ModuleList(
            ConvEncoder(
                config.prefix_width, config.keypoints, config.conv_width, config.image_downsample, config.random_shift
            )
            for _ in range(config.cameras if config.image_encoder == "conv" else 0)
        )
        self.prefix_position = nn.Parameter(0.02 * torch.randn(config.prefix_length, config.prefix_width))
        self.prefix_layers = nn.ModuleList(PrefixLayer(config) for _ in range(config.num_layers))

        width = config.expert_width
        self.action_projection = nn.Linear(config.action_dim, width)
        self.action_position = nn.Parameter(0.02 * torch.randn(config.chunk_length, width))
        self.time_mlp = nn.Sequential(nn.Linear(width, width), nn.SiLU(), nn.Linear(width, width))
        self.expert_layers = nn.ModuleList(ExpertLayer(config) for _ in range(config.num_layers))
        self.final_norm = RMSNorm(width, affine=False)
        self.final_modulation = nn.Linear(width, 2 * width)
        nn.init.zeros_(self.final_modulation.weight)
        nn.init.zeros_(self.final_modulation.bias)
        self.velocity_head = nn.Linear(width, config.action_dim)

    def prefix_parameters(self) -> list[nn.Parameter]:
        """The "VLM" side: frozen during distillation by default, as the paper freezes the VLM."""
        modules = [self.token_embedding, self.state_projection, self.prefix_layers, self.camera_encoders]
        if self.patch_embedding is not None:
            modules.append(self.patch_embedding)
        return [self.prefix_position] + [parameter for module in modules for parameter in module.parameters()]

    def encode(self, observation: dict[str, Tensor]) -> dict[str, Tensor]:
        """Prefix pass. ``observation``: ``state`` (B, state_dim), ``tokens`` (B, T) int, ``token_mask``
        (B, T) bool, and when the config uses images, uint8 frames (B, 3, S, S): ``image`` of the main camera and
        ``image.<camera>`` of each extra camera. Returns the cached keys / values (B, layers, heads, P, head_dim) and
        the prefix mask (B, P)."""
        config = self.config
        state, tokens, token_mask = observation["state"], observation["tokens"], observation["token_mask"]
        batch = state.shape[0]
        if state.shape != (batch, config.state_dim):
            raise ValueError(f"state must have shape (B, {config.state_dim}), got {tuple(state.shape)}")
        if tokens.shape != (batch, config.max_instruction_tokens) or token_mask.shape != tokens.shape:
            raise ValueError(
                f"tokens and token_mask must have shape (B, {config.max_instruction_tokens}), got {tuple(tokens.shape)} and {tuple(token_mask.shape)}"
            )
        parts = [self.token_embedding(tokens), self.state_projection(state)[:, None]]
        masks = [token_mask, token_mask.new_ones(batch, 1)]
        if config.use_image:
            images = [self._camera(observation, key) for key in camera_keys(config)]
            if self.patch_embedding is not None:
                parts.append(self.patch_embedding(images[0].float() / 255.0).flatten(2).transpose(1, 2))
            else:
                parts += [encoder(image) for encoder, image in zip(self.camera_encoders, images, strict=True)]
            masks.append(token_mask.new_ones(batch, config.image_tokens))
        x = torch.cat(parts, dim=1) + self.prefix_position
        mask = torch.cat(masks, dim=1)
        keys, values = [], []
        for layer in self.prefix_layers:
            x, k, v = layer(x, mask)
            keys.append(k)
            values.append(v)
        return {"keys": torch.stack(keys, dim=1), "values": torch.stack(values, dim=1), "mask": mask}

    def _camera(self, observation: dict[str, Tensor], key: str) -> Tensor:
        image = observation.get(key)
        expected = (observation["state"].shape[0], 3, self.config.image_size, self.config.image_size)
        if image is None or tuple(image.shape) != expected or image.dtype != torch.uint8:
            got = None if image is None else f"{tuple(image.shape)} {image.dtype}"
            raise ValueError(f"{key} must be uint8 frames of shape {expected}, got {got}")
        return image

    def embed_time(self, t: Tensor) -> Tensor:
        return self.time_mlp(sinusoidal_features(t, self.time_embedding_dim).to(self.time_mlp[0].weight.dtype))

    def velocity_from_time_embedding(self, x_t: Tensor, time_embedding: Tensor, context: dict[str, Tensor]) -> Tensor:
        """The velocity of ``x_t`` (B, chunk, action_dim) given a time embedding (B, width) or (B, chunk, width)."""
        expected = (self.config.chunk_length, self.config.action_dim)
        if tuple(x_t.shape[1:]) != expected:
            raise ValueError(f"noisy actions must have shape (B, {expected[0]}, {expected[1]}), got {tuple(x_t.shape)}")
        if time_embedding.ndim == 3 and time_embedding.shape[1] != expected[0]:
            raise ValueError(
                f"a time embedding per action must have shape (B, {expected[0]}, width), got "
                f"{tuple(time_embedding.shape)}"
            )
        condition = F.silu(time_embedding)
        x = self.action_projection(x_t) + self.action_position
        for index, layer in enumerate(self.expert_layers):
            x = layer(x, condition, context["keys"][:, index], context["values"][:, index], context["mask"])
        scale, shift = _per_action(self.final_modulation(condition)).chunk(2, dim=-1)
        return self.velocity_head(self.final_norm(x) * (1 + scale) + shift)
