"""LeRobot's MolmoAct2Policy under SnapFlow (LeRobot >= 0.6.1).

MolmoAct2 encodes the observation once: its Molmo2 VLM (a SigLIP2 tower pooled into image tokens, and a Qwen3
language model over the cameras, the discretised state and the task as one prompt) fills a key/value cache, whose
keys and values of every layer the action expert reads through its context projections (``prepare_context``): the
frozen prefix, all that LeRobot's own sampler runs once a chunk. Each step its action expert, one block per language
layer, embeds the noisy chunk, self-attends, cross-attends to its layer's projected keys and values, and its output
layer gives the velocity; the time enters through ``time_embed``, whose output conditions every block's adaptive
norms and the output layer: phi_s(s) is added to it.

Its flow runs the other way from snapflow's (t = 0 noise, t = 1 data, velocity data - noise): snapflow's time is
1 - t and its velocity the negative of MolmoAct2's. Its noise is a standard normal, zero on the action width's padding
(32 wide), where its velocity and chunk are zeroed too; its loss leaves that padding out. By default it integrates
10 Euler steps a chunk. Its discrete action head (FAST tokens decoded one at a time) is not a flow: a student samples
the continuous head.
"""

from __future__ import annotations

import functools
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch
from torch import Tensor, nn

from snapflow.adapters.lerobot.base import (
    ACTION,
    OBS_STATE,
    ChunkSampler,
    LeRobotFlowPolicy,
    modeling_module,
    split_timestep,
)
from snapflow.errors import InvalidInputError
from snapflow.nn.time_embedding import TargetTimeEmbedding

#: the pre-processor's image tensors, laid out crop after crop over the whole batch (MolmoAct2's processor flattens
#: every image of every row); :meth:`MolmoAct2FlowPolicy.example_observation` gives them a leading row axis instead
IMAGE_FIELDS = ("pixel_values", "image_token_pooling", "image_grids", "image_num_crops")
#: LeRobot's model dtypes by name (its config's ``model_dtype``)
DTYPES = {"float32": torch.float32, "bfloat16": torch.bfloat16, "float16": torch.float16}


@dataclass(frozen=True)
class MolmoAct2TimeSampler:
    """MolmoAct2's training times in snapflow's direction. Its time is offset + (upper - offset) * Beta(1, beta), with
    upper = min(cutoff, offset + scale); snapflow's, 1 minus it, is low + (high - low) * Beta(beta, 1), with low =
    1 - upper and high = 1 - offset: drawn by inverting Beta(beta, 1)'s CDF, u ** (1 / beta), from the caller's
    generator. At MolmoAct2's defaults (beta 1.5, offset 0.001, scale 0.999) that is 0.999 * Beta(1.5, 1)."""

    concentration: float = 1.5
    low: float = 0.0
    high: float = 0.999

    def __post_init__(self) -> None:
        if self.concentration <= 0 or not 0 <= self.low <= self.high <= 1:
            raise InvalidInputError(f"not a MolmoAct2 time distribution: {self}")

    def __call__(
        self, batch_size: int, *, device: torch.device | str = "cpu", generator: torch.Generator | None = None
    ) -> Tensor:
        u = torch.rand(batch_size, device=device, generator=generator)
        return self.low + (self.high - self.low) * u.pow(1 / self.concentration)


def _conditioning_with_target_time(expert: nn.Module, target_time_embedding: nn.Module, timesteps: Tensor) -> Tensor:
    """The action expert's ``_time_conditioning`` (sinusoid, then ``time_embed``'s MLP) with phi_s(s) added to it.
    LeRobot's own (B,) timestep is MolmoAct2's time, read as s = 1 - it (snapflow's t); the adapter's (B, 2) is
    [MolmoAct2's time, snapflow's s]."""
    own, s = (timesteps, 1 - timesteps) if timesteps.ndim == 1 else timesteps.unbind(dim=1)
    conditioning = type(expert)._time_conditioning(expert, own)
    return conditioning + target_time_embedding(s).to(conditioning.dtype)


@functools.lru_cache(maxsize=16)
def _checkpoint_steps(checkpoint_path: str) -> int:
    """The Euler steps the MolmoAct2 checkpoint ``checkpoint_path`` (a local folder, or a hub id in the local cache)
    samples by default: its ``flow_matching_num_steps`` (MolmoAct2's 10)."""
    from huggingface_hub import try_to_load_from_cache

    folder = Path(checkpoint_path).expanduser()
    path = folder / "config.json" if folder.is_dir() else try_to_load_from_cache(checkpoint_path, "config.json")
    saved = json.loads(Path(path).read_text()) if isinstance(path, (str, Path)) and Path(path).is_file() else {}
    return int(saved.get("flow_matching_num_steps", 10))


class MolmoAct2FlowPolicy(LeRobotFlowPolicy):
    """SnapFlow view of a LeRobot ``MolmoAct2Policy``: the VLM's pass and the expert's context projections are the
    frozen prefix; the action expert's time MLP, action embedding, blocks and output layer the action expert."""

    policy_type = "molmoact2"
    steps_field = "num_inference_steps"
    minimum_lerobot = "0.6.1"
    # its processor pads prompts on the left (its BOS insertion assumes it), which moves the prompt's rotary positions
    masks_prompt_padding = False
    export_refusal = (
        "MolmoAct2's prefix lays each row's image crops and pooled tokens out on the host (build_batched_images: "
        ".tolist() and .item() over the batch), which torch.export cannot trace"
    )

    def __init__(self, policy: nn.Module) -> None:
        """The adapter of ``policy``, refused where it samples discrete tokens; its continuous head is the one
        LeRobot's action API samples from now on."""
        config = policy.config
        if config.action_mode == "discrete" or config.inference_action_mode == "discrete":
            raise InvalidInputError(
                "this molmoact2 policy decodes its actions as discrete FAST tokens, one at a time: there is no velocity "
                "field to jump along; snapflow distils its continuous flow-matching head (action_mode 'continuous' or "
                "'both', inference_action_mode 'continuous')"
            )
        config.inference_action_mode = "continuous"  # the head a student samples; LeRobot asks for it by name
        super().__init__(policy)
        self.training_time_sampler(config)  # refuses, by name, times snapflow cannot sample

    @property
    def expert(self) -> nn.Module:
        """MolmoAct2's ``ActionExpert``: its context projections (prefix) and the action expert."""
        return self.policy._action_expert()

    @property
    def time_owner(self) -> nn.Module:
        # the policy itself: it holds LeRobot's RTC processor and config, which LeRobot's sampling reads there
        return self.policy

    def new_target_time_embedding(self) -> TargetTimeEmbedding:
        return TargetTimeEmbedding(self.expert.hidden_size)

    def install_target_time(self, model: nn.Module) -> None:
        # bound to phi_s itself, not to the policy that holds both: no module cycle
        expert = self.expert
        expert._time_conditioning = functools.partial(
            _conditioning_with_target_time, expert, model.target_time_embedding
        )

    def expert_modules(self) -> list[nn.Module]:
        # the context projections (context_k_proj, context_v_proj) run once a chunk on the prefix: frozen with it
        expert = self.expert
        return [expert.time_embed, expert.action_embed, expert.blocks, expert.final_layer]

    @classmethod
    def own_steps(cls, config: Any) -> int:
        """``num_inference_steps`` where the config sets it, the checkpoint's ``flow_matching_num_steps`` otherwise."""
        return config.num_inference_steps or _checkpoint_steps(config.checkpoint_path)

    @classmethod
    def chunk_shape(cls, config: Any) -> tuple[int, int]:
        """MolmoAct2's noise: ``chunk_size`` steps of ``expected_max_action_dim`` (32) actions; LeRobot's
        ``predict_action_chunk`` cuts the width to the robot's after sampling."""
        return config.chunk_size, config.expected_max_action_dim

    @classmethod
    def training_time_sampler(cls, config: Any) -> MolmoAct2TimeSampler:
        """MolmoAct2's shifted Beta(alpha, beta) times (:class:`MolmoAct2TimeSampler`); snapflow samples alpha = 1."""
        alpha, beta = config.flow_matching_beta_alpha, config.flow_matching_beta_beta
        if alpha != 1.0:
            raise InvalidInputError(
                f"this molmoact2 samples times from Beta({alpha}, {beta}); snapflow samples Beta(1, b) only"
            )
        offset = config.flow_matching_time_offset
        upper = min(config.flow_matching_cutoff, offset + config.flow_matching_time_scale)
        # rounded: 1 - 0.001 is 0.9990000000000000002 in floating point
        return MolmoAct2TimeSampler(beta, round(1.0 - upper, 12), round(1.0 - offset, 12))

    def run_in(self, dtype: torch.dtype) -> None:
        """LeRobot's own reduced precision: the whole model in ``dtype`` (LeRobot loads it in its config's
        ``model_dtype``), its sampling under autocast to it; phi_s stays in float32."""
        names = {value: name for name, value in DTYPES.items() if value != torch.float32}
        if dtype not in names:
            super().run_in(dtype)
        self.policy.model.to(dtype)
        self.policy.config.model_dtype = names[dtype]

    def autocast(self, device_type: str) -> torch.autocast:
        """LeRobot's precision: autocast to its config's reduced ``model_dtype`` (its ``predict_action_chunk``), or
        the caller's own (``lerobot-train``'s), without autocast's weight cache, which would hand the objective's
        gradient pass weights cast without a graph in its no-grad target pass."""
        dtype = DTYPES[self.policy.config.model_dtype]
        if dtype != torch.float32:
            return torch.autocast(device_type, dtype=dtype, cache_enabled=False)
        enabled = torch.is_autocast_enabled(device_type)
        own = torch.get_autocast_dtype(device_type)
        return torch.autocast(device_type, dtype=own, enabled=enabled, cache_enabled=False)

    def _width(self, pad: Tensor | None) -> Tensor | None:
        """(B, 1, 32): true on the robot's action width, where LeRobot masks the padding (``mask_action_dim_padding``
        and the pre-processor's ``action_dim_is_pad``, ``pad``); None where it masks nothing."""
        if pad is None or not self.policy.config.mask_action_dim_padding:
            return None
        return ~pad.to(torch.bool)[:, None, :]

    def action_targets(self, batch: dict[str, Tensor]) -> Tensor:
        """The pre-processor's chunk, padded to 32 and zero on the padding, as MolmoAct2's training forward reads it."""
        width = self._width(batch.get("action_dim_is_pad"))
        return batch[ACTION] if width is None else batch[ACTION].masked_fill(~width, 0)

    def action_weights(self, batch: dict[str, Tensor]) -> Tensor | None:
        """MolmoAct2's loss weights (:class:`snapflow.protocol.PaddedActions`): the robot's action width, and in
        training the steps before an episode's end. MolmoAct2 averages each step over the width and the chunk over all
        its steps, the ones past the end counted as zeros; the objective's mean leaves those out of its count too."""
        weights = self._width(batch.get("action_dim_is_pad"))
        horizon = batch.get("action_horizon_is_pad")
        if horizon is not None:
            steps = ~horizon.to(torch.bool)[:, :, None]
            weights = steps if weights is None else weights & steps
        return None if weights is None else weights.float()

    def flow_noise(self, shape: tuple[int, ...], generator: Any = None, device: Any = None) -> Tensor:
        """MolmoAct2's noise (:class:`snapflow.protocol.OwnNoise`): a standard normal, zero past the robot's action
        width where the policy masks its padding."""
        noise = torch.randn(shape, generator=generator, device=device)
        if not self.policy.config.mask_action_dim_padding:
            return noise
        width = self.policy.config.output_features[ACTION].shape[0]
        return noise * (torch.arange(shape[-1], device=noise.device) < width)

    def draw_noise(self, context: dict[str, Any], batch_size: int, generator: Any = None) -> Tensor:
        """LeRobot's own draw (``generate_actions_from_inputs``): a standard normal in the expert's dtype after the
        prefix, from its generator (torch's global one where None), zero on the padded width."""
        weight = self.expert.action_embed.weight
        noise = torch.randn(
            (batch_size, *self.action_shape), generator=generator, device=weight.device, dtype=weight.dtype
        )
        width = context.get("action_width")
        return noise if width is None else noise.masked_fill(~width, 0)

    def model_inputs(self, batch: dict[str, Tensor]) -> tuple[Any, ...]:
        """What MolmoAct2Policy's ``predict_action_chunk`` hands its VLM and expert: the model's inputs (prompt ids,
        image crops and pooling, in the model's dtype) and the action width's padding."""
        if batch["image_num_crops"].ndim == 2:  # rows lead (:meth:`example_observation`): laid out as the pre-processor
            batch = {**batch, **{key: batch[key].flatten(0, 1) for key in IMAGE_FIELDS}}
        return self.policy._model_inputs(batch), batch.get("action_dim_is_pad")

    def encode(self, batch: dict[str, Tensor]) -> dict[str, Any]:
        """The prefix of :meth:`model_inputs`; a training batch whose chunks run past an episode's end has its steps
        masked as MolmoAct2's training forward masks them (the expert's hidden states and self-attention)."""
        context = super().encode(batch)
        horizon = batch.get("action_horizon_is_pad")
        if ACTION in batch and horizon is not None and bool(horizon.any()):
            context["valid_action"] = (~horizon.to(torch.bool))[:, :, None].to(self.expert.action_embed.weight.dtype)
        return context

    def encode_inputs(self, inputs: dict[str, Tensor], action_dim_is_pad: Tensor | None) -> dict[str, Any]:
        """The VLM's pass over the prompt and cameras (its per-layer keys and values, depth-gated where the checkpoint
        gates them), and the expert's context projections of them, as ``generate_actions_from_inputs`` runs them once
        a chunk; the cross-attention's padding mask and the action width's."""
        policy, backbone, expert = self.policy, self.policy._backbone(), self.expert
        device = next(expert.parameters()).device.type
        with self.prefix_pass(backbone), self.autocast(device):
            outputs = backbone(**inputs, use_cache=True, output_attentions=False, output_hidden_states=False)
            layers = backbone._extract_kv_states(outputs.past_key_values)
            ids = inputs.get("input_ids")
            mask = policy._encoder_attention_mask_for_action_expert(
                input_ids=ids, attention_mask=inputs.get("attention_mask")
            )
            gate, depth = backbone._depth_gate_from_condition(
                input_ids=ids, encoder_attention_mask=mask, layer_kv_states=layers
            )
            layers = backbone._apply_depth_gate_to_layer_kv_states(layers, depth, gate)
            context: dict[str, Any] = {"kv": tuple(expert._prepare_kv_context(layers))}
            cross = expert._build_cross_attention_mask(mask, layers[0][0].shape[0], expert.action_embed.weight.dtype)
        if cross is not None:
            context["cross_mask"] = cross
        width = self._width(action_dim_is_pad)
        if width is not None:
            context["action_width"] = width
        return context

    def denoise(self, context: dict[str, Any], x_t: Tensor, timestep: Tensor) -> Tensor:
        """MolmoAct2's ``forward_with_context`` at snapflow's time t (MolmoAct2's 1 - t), phi_s(s) added to its time
        conditioning, its velocity zero on the padded width and negated."""
        with self.autocast(x_t.device.type):
            return self._velocity(context, x_t, *split_timestep(timestep)).to(x_t.dtype)

    def _velocity(self, context: dict[str, Any], x_t: Tensor, t: Tensor, s: Tensor) -> Tensor:
        """:meth:`denoise` in the expert's dtype, under the caller's autocast."""
        expert = self.expert
        dtype, horizon, valid = expert.action_embed.weight.dtype, x_t.shape[1], context.get("valid_action")
        rope = expert.blocks[0].self_attn.rope if len(expert.blocks) else None
        steps = None if valid is None else valid[..., 0] > 0
        # per call, not in the context: the rotary table and a causal mask lead with no batch rows to select
        own_context = modeling_module(expert).ActionExpertContext(
            kv_contexts=context["kv"],
            cross_mask=context.get("cross_mask"),
            self_mask=expert._build_self_attention_mask(steps, horizon, x_t.device, dtype),
            valid_action=valid,
            rope_cache=None if rope is None else rope.build_cache(seq_len=horizon, device=x_t.device, dtype=dtype),
        )
        timesteps = torch.stack([1 - t, s], dim=1)
        velocity = expert.forward_with_context(x_t.to(dtype), timesteps, context=own_context)
        width = context.get("action_width")
        return -(velocity if width is None else velocity.masked_fill(~width, 0))

    def example_observation(self, device: torch.device) -> dict[str, Any]:
        """MolmoAct2's own pre-processor's batch of one random frame (its tokenizer and image processor read from the
        checkpoint), its image tensors under a leading row axis, which :meth:`model_inputs` reads too: a batch of
        this frame repeated is its rows repeated."""
        from lerobot.policies.molmoact2.processor_molmoact2 import make_molmoact2_pre_post_processors

        config = self.policy.config
        widths = {OBS_STATE: config.robot_state_feature.shape, ACTION: config.action_feature.shape}
        stats = {key: {"q01": -torch.ones(shape), "q99": torch.ones(shape)} for key, shape in widths.items()}
        preprocessor, _ = make_molmoact2_pre_post_processors(config, dataset_stats=stats)
        frame = {key: torch.rand(1, *feature.shape) for key, feature in config.image_features.items()}
        batch = preprocessor({**frame, OBS_STATE: torch.rand(1, *widths[OBS_STATE]) * 2 - 1, "task": ["perform it"]})
        rows = {key: batch[key][None] for key in IMAGE_FIELDS}
        return {key: value.to(device) for key, value in {**batch, **rows}.items() if torch.is_tensor(value)}

    def install_sampler(self, sample: ChunkSampler) -> None:
        """LeRobot's two continuous samplers, its own and its RTC one, replaced on the instances: the prefix once, the
        noise LeRobot would draw (its generator's), then ``sample``."""

        def chunk(inputs: dict[str, Tensor], action_dim_is_pad: Tensor | None, generator: Any, *rtc: Any) -> Tensor:
            """One chunk from the model's inputs; ``rtc``: LeRobot's delay, previous chunk and horizon, if any."""
            context = self.encode_inputs(inputs, action_dim_is_pad)
            noise = self.draw_noise(context, context["kv"][0][0].shape[0], generator)
            return sample((), noise, *rtc, context=context)

        def generate_actions_from_inputs(
            *, action_dim_is_pad: Tensor | None = None, generator: Any = None, **inputs: Any
        ) -> Tensor:
            inputs = {key: value for key, value in inputs.items() if key not in ("action_horizon", "num_steps")}
            return chunk(inputs, action_dim_is_pad, generator)

        def generate_actions_from_inputs_with_rtc(
            *,
            model_inputs: dict[str, Tensor],
            action_dim_is_pad: Tensor | None,
            num_steps: int | None,
            generator: Any,
            inference_delay: int | None,
            prev_chunk_left_over: Tensor | None,
            execution_horizon: int | None,
        ) -> Tensor:
            return chunk(
                model_inputs, action_dim_is_pad, generator, inference_delay, prev_chunk_left_over, execution_horizon
            )

        self.policy._backbone().generate_actions_from_inputs = generate_actions_from_inputs
        self.policy._generate_actions_from_inputs_with_rtc = generate_actions_from_inputs_with_rtc


__all__ = ["MolmoAct2FlowPolicy", "MolmoAct2TimeSampler"]
