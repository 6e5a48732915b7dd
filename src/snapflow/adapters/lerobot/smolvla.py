"""LeRobot's SmolVLAPolicy as a :class:`snapflow.protocol.FlowPolicy`.

SmolVLA fuses time into every action token: ``action_time_mlp_out(SiLU(action_time_mlp_in([a, sin(t)])))``.
phi_s(s) is added to the output of ``action_time_mlp_in``, before the SiLU. The target time reaches it
explicitly, with no hook and no stored state: the policy's ``embed_suffix`` is replaced on the instance
(LeRobot's files stay untouched) by one that reads a timestep of shape (B, 2) as [t, s]. A plain (B,)
timestep means s = t, so LeRobot's own ``forward`` and ``sample_actions`` keep running the flow-matching
teacher. ``denoise_step`` passes the timestep through untouched, so one pass is one ``denoise_step`` call
against the prefix cache that :meth:`SmolVLAFlowPolicy.encode` built once.
"""

from __future__ import annotations

import types
from pathlib import Path
from typing import Any

import torch
from torch import Tensor, nn
from torch.nn import functional as F

from snapflow.flow.solver import SNAPFLOW_1, SamplingMode, euler_sample
from snapflow.io import write_json
from snapflow.nn.time_embedding import TargetTimeEmbedding
from snapflow.training.checkpoint import CheckpointError, load_state_strict, read_tensors

try:
    from lerobot.policies.smolvla.modeling_smolvla import create_sinusoidal_pos_embedding, make_att_2d_masks
except ImportError as error:  # pragma: no cover - depends on the environment
    raise ImportError('the LeRobot adapters need LeRobot: pip install "snapflow[lerobot]"') from error

OBS_LANGUAGE_TOKENS = "observation.language.tokens"
OBS_LANGUAGE_ATTENTION_MASK = "observation.language.attention_mask"


def _embed_suffix_with_target_time(self: nn.Module, noisy_actions: Tensor, timestep: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    """SmolVLA's suffix embedding with phi_s(s) added after ``action_time_mlp_in``; bound to a VLAFlowMatching."""
    t, s = (timestep, timestep) if timestep.ndim == 1 else timestep.unbind(dim=1)
    action_embedding = self.action_in_proj(noisy_actions)
    batch, chunk, width = action_embedding.shape
    time_embedding = create_sinusoidal_pos_embedding(
        t, width, self.config.min_period, self.config.max_period, device=action_embedding.device
    ).to(action_embedding.dtype)
    fused = self.action_time_mlp_in(torch.cat([action_embedding, time_embedding[:, None, :].expand_as(action_embedding)], dim=2))
    fused = fused + self.target_time_embedding(s).to(fused.dtype)[:, None, :]
    embeddings = self.action_time_mlp_out(F.silu(fused))
    pad_masks = torch.ones(batch, chunk, dtype=torch.bool, device=embeddings.device)
    # SmolVLA's layout: each action token opens its own attention block, so actions attend causally among
    # themselves and to the whole prefix
    att_masks = torch.ones(batch, chunk, dtype=embeddings.dtype, device=embeddings.device)
    return embeddings, pad_masks, att_masks


def add_target_time_embedding(flow_model: nn.Module) -> TargetTimeEmbedding:
    """Attach phi_s to a SmolVLA ``VLAFlowMatching`` (saved with its state dict) and route s through it."""
    if not hasattr(flow_model, "target_time_embedding"):
        width = flow_model.vlm_with_expert.expert_hidden_size
        config = flow_model.config
        embedding = TargetTimeEmbedding(width, min_period=config.min_period, max_period=config.max_period)
        flow_model.target_time_embedding = embedding.to(next(flow_model.action_time_mlp_in.parameters()).device)
        flow_model.embed_suffix = types.MethodType(_embed_suffix_with_target_time, flow_model)
    return flow_model.target_time_embedding


class SmolVLAFlowPolicy(nn.Module):
    """SnapFlow view of a LeRobot ``SmolVLAPolicy``; batches are what the policy's pre-processor produces
    (normalised state, images in [0, 1], language tokens and mask). Actions are (B, chunk_size, max_action_dim),
    as ``policy.prepare_action(batch)`` pads them."""

    def __init__(self, policy: nn.Module) -> None:
        super().__init__()
        self.policy = policy
        add_target_time_embedding(policy.model)

    @property
    def target_time_embedding(self) -> TargetTimeEmbedding:
        """phi_s, stored inside the LeRobot model so that LeRobot's own checkpoints carry it (registered once:
        safetensors refuses tensors saved under two names)."""
        return self.policy.model.target_time_embedding

    def expert_parameters(self) -> list[nn.Parameter]:
        """What distillation trains, as in the paper: the action expert, its projections and phi_s; the VLM
        (and the state projection, which feeds the VLM prefix) stay frozen."""
        model = self.policy.model
        modules = [model.vlm_with_expert.lm_expert, model.action_in_proj, model.action_out_proj,
                   model.action_time_mlp_in, model.action_time_mlp_out, model.target_time_embedding]
        return [parameter for module in modules for parameter in module.parameters()]

    def encode(self, batch: dict[str, Tensor]) -> dict[str, Any]:
        """Prefix pass: images, instruction and state through the VLM once, keeping its key/value cache."""
        images, image_masks = self.policy.prepare_images(batch)
        return self.encode_inputs(images, image_masks, batch[OBS_LANGUAGE_TOKENS], batch[OBS_LANGUAGE_ATTENTION_MASK],
                                  self.policy.prepare_state(batch))

    def encode_inputs(self, images: list[Tensor], image_masks: list[Tensor], tokens: Tensor, token_masks: Tensor, state: Tensor) -> dict[str, Any]:
        """:meth:`encode` from the model-level inputs LeRobot's ``sample_actions`` receives."""
        model = self.policy.model
        prefix, pad_masks, att_masks = model.embed_prefix(images, image_masks, tokens, token_masks, state=state)
        _, cache = model.vlm_with_expert.forward(
            attention_mask=make_att_2d_masks(pad_masks, att_masks), position_ids=torch.cumsum(pad_masks, dim=1) - 1,
            past_key_values=None, inputs_embeds=[prefix, None], use_cache=True, fill_kv_cache=True,
        )
        return {"cache": cache, "prefix_pad_masks": pad_masks}

    def use_sampling_mode(self, mode: SamplingMode) -> None:
        """Make LeRobot's own ``predict_action_chunk`` / ``select_action`` sample with ``mode``: SnapFlow 1-NFE
        for deployment, or ``teacher-N`` to run the same checkpoint as the N-step teacher."""
        adapter = self

        def sample_actions(model, images, img_masks, lang_tokens, lang_masks, state, noise=None, **_):
            if noise is None:
                noise = model.sample_noise((state.shape[0], model.config.chunk_size, model.config.max_action_dim), state.device)
            context = adapter.encode_inputs(images, img_masks, lang_tokens, lang_masks, state)
            return euler_sample(lambda x, t, s: adapter.velocity(x, t, s, context), noise, mode)

        self.policy.model.sample_actions = types.MethodType(sample_actions, self.policy.model)
        self.policy.reset()

    def velocity(self, x_t: Tensor, t: Tensor, s: Tensor, context: dict[str, Any]) -> Tensor:
        # each pass gets its own cache containers over the shared tensors, so no pass can alter another's
        cache = {layer: dict(entry) for layer, entry in context["cache"].items()}
        return self.policy.model.denoise_step(context["prefix_pad_masks"], cache, x_t, torch.stack([t, s], dim=1))


SNAPFLOW_MARKER = "snapflow.json"


def save_smolvla(adapter: SmolVLAFlowPolicy, directory: str | Path) -> Path:
    """LeRobot's own layout (``config.json`` + ``model.safetensors``, phi_s included) plus a marker file."""
    directory = Path(directory)
    adapter.policy.save_pretrained(directory)
    write_json(directory / SNAPFLOW_MARKER, {"format": "snapflow-lerobot", "policy": "smolvla", "target_time": True})
    return directory


def load_smolvla(directory: str | Path, mode: SamplingMode = SNAPFLOW_1) -> SmolVLAFlowPolicy:
    """Rebuild a saved SnapFlow SmolVLA, load every tensor strictly, and make LeRobot's own action API sample
    with ``mode`` (SnapFlow 1-NFE by default). (LeRobot's ``from_pretrained`` loads non-strictly, so on its
    own it would silently drop phi_s and give back the teacher.)"""
    from lerobot.configs.policies import PreTrainedConfig
    from lerobot.policies.smolvla.modeling_smolvla import SmolVLAPolicy

    directory = Path(directory)
    if not (directory / SNAPFLOW_MARKER).is_file():
        raise CheckpointError(f"{directory} is not a SnapFlow-distilled LeRobot policy (no {SNAPFLOW_MARKER})")
    adapter = SmolVLAFlowPolicy(SmolVLAPolicy(PreTrainedConfig.from_pretrained(directory)))
    load_state_strict(adapter.policy, read_tensors(directory / "model.safetensors"), directory / "model.safetensors")
    adapter.use_sampling_mode(mode)
    return adapter


__all__ = ["SmolVLAFlowPolicy", "add_target_time_embedding", "save_smolvla", "load_smolvla"]
