"""LeRobot's GrootPolicy (NVIDIA GR00T N1.7) under SnapFlow (LeRobot >= 0.6).

GR00T encodes the observation once: its Qwen3-VL backbone (the vision tower and the language model cut to
``select_layer`` layers), then the action head's ``vlln`` and VL self-attention over those features, and the state
through its state encoder (``_encode_features``): the frozen prefix. Each step its action encoder reads the noisy chunk
and the time, and the DiT, which cross-attends to the prefix's features (image and text tokens in turn), and the action
decoder give the velocity: the action expert.

Its flow runs the other way from snapflow's (t = 0 noise, t = 1 data, velocity data - noise): snapflow's time is
1 - t and its velocity the negative of GR00T's. GR00T's time enters as a bucket, int(1000 t), into the action
encoder's sinusoid and the DiT's ``timestep_encoder``, whose output (``temb``) drives every block's adaptive layer norm
and the output modulation; phi_s(s) is added to ``temb``. By default it integrates 4 Euler steps a chunk.
"""

from __future__ import annotations

import functools
import json
from pathlib import Path
from typing import Any

import torch
from torch import Tensor, nn

from snapflow.adapters.lerobot.base import ACTION, OBS_STATE, ChunkSampler, LeRobotFlowPolicy, split_timestep
from snapflow.errors import InvalidInputError
from snapflow.flow.time_sampling import BetaTimeSampler
from snapflow.nn.time_embedding import TargetTimeEmbedding

#: what makes snapflow's float32 grid land on GR00T's own buckets: 1 - 0.7 rounds to 0.29999998 in float32, a
#: bucket below GR00T's int(1000 * 3 / 10) without it, while no bucket moves by more than a 1000th of itself
BUCKET_ROUNDING = 1e-3
#: the GR00T N1.7 fields the chunk's shape and the training times are read from, at their defaults (the checkpoint's
#: config.json, not LeRobot's GrootConfig, holds them)
CHECKPOINT_DEFAULTS = {
    "action_horizon": 40,
    "num_inference_timesteps": 4,
    "noise_beta_alpha": 1.5,
    "noise_beta_beta": 1.0,
    "noise_s": 0.999,
    "max_state_dim": 132,
    "max_action_dim": 132,
}


def _timestep_encoder_with_target_time(
    encoder: nn.Module, target_time_embedding: nn.Module, buckets: int, timestep: Tensor
) -> Tensor:
    """GR00T's ``TimestepEncoder.forward`` with phi_s(s) added to its output. LeRobot's own (B,) timestep is GR00T's
    bucket b, read as s = 1 - b / buckets (snapflow's t); the adapter's (B, 2) is [GR00T's bucket, snapflow's s]."""
    bucket, s = (timestep, 1 - timestep / buckets) if timestep.ndim == 1 else timestep.unbind(dim=1)
    embedding = type(encoder).forward(encoder, bucket)
    return embedding + target_time_embedding(s).to(embedding.dtype)


@functools.lru_cache(maxsize=16)
def _checkpoint_fields(base_model_path: str) -> dict[str, Any]:
    """:data:`CHECKPOINT_DEFAULTS` as the GR00T checkpoint ``base_model_path`` (a local folder, or a hub id found in
    the local cache) sets them."""
    from huggingface_hub import try_to_load_from_cache

    folder = Path(base_model_path).expanduser()
    path = folder / "config.json" if folder.is_dir() else try_to_load_from_cache(base_model_path, "config.json")
    saved = json.loads(Path(path).read_text()) if isinstance(path, (str, Path)) and Path(path).is_file() else {}
    return {name: saved.get(name, default) for name, default in CHECKPOINT_DEFAULTS.items()}


class GrootFlowPolicy(LeRobotFlowPolicy):
    """SnapFlow view of a LeRobot ``GrootPolicy`` (GR00T N1.7): the Qwen3-VL backbone, the VL self-attention and the
    state encoder are the frozen prefix; the action encoder, the DiT and the action decoder the action expert."""

    policy_type = "groot"
    steps_field = "num_inference_timesteps"
    minimum_lerobot = "0.6"
    # the prefix's VL self-attention attends to every prompt token, padding included (left padding besides)
    masks_prompt_padding = False
    export_refusal = (
        "Qwen3-VL's multimodal rotary positions walk the prompt's tokens on the host (.tolist()), which torch.export "
        "cannot trace"
    )

    def __init__(self, policy: nn.Module) -> None:
        config = policy.config
        checkpoint = _checkpoint_fields(config.base_model_path)
        for width in ("max_state_dim", "max_action_dim"):  # GR00T itself fails deep in its encoders otherwise
            if getattr(config, width) != checkpoint[width]:
                raise InvalidInputError(
                    f"this groot's config pads to {width}={getattr(config, width)}, but its checkpoint "
                    f"{config.base_model_path} was built for {checkpoint[width]}: give the config the checkpoint's"
                )
        super().__init__(policy)
        self.training_time_sampler(config)  # refuses, by name, times snapflow cannot sample

    @property
    def head(self) -> nn.Module:
        """GR00T's action head: the prefix's VL self-attention and state encoder, and the action expert."""
        return self.policy._groot_model.action_head

    @property
    def time_owner(self) -> nn.Module:
        return self.head.model

    def new_target_time_embedding(self) -> TargetTimeEmbedding:
        return TargetTimeEmbedding(self.head.model.inner_dim)

    def install_target_time(self, model: nn.Module) -> None:
        # bound to phi_s itself, not to the policy that holds both: no module cycle
        encoder = model.timestep_encoder
        buckets = self.head.num_timestep_buckets
        encoder.forward = functools.partial(
            _timestep_encoder_with_target_time, encoder, model.target_time_embedding, buckets
        )

    def expert_modules(self) -> list[nn.Module]:
        head = self.head
        position = [head.position_embedding] if head.config.add_pos_embed else []
        return [head.action_encoder, *position, head.model, head.action_decoder]

    @classmethod
    def own_steps(cls, config: Any) -> int:
        """``num_inference_timesteps`` where the config sets it, the checkpoint's otherwise (GR00T N1.7's: 4)."""
        return config.num_inference_timesteps or _checkpoint_fields(config.base_model_path)["num_inference_timesteps"]

    @classmethod
    def chunk_shape(cls, config: Any) -> tuple[int, int]:
        """GR00T's own noise: the checkpoint's ``action_horizon`` by ``max_action_dim``. Both paddings are kept: its
        DiT reads every padded entry of the noisy chunk (they steer the real ones), so the teacher is the same only on
        the padded chunk; LeRobot's ``predict_action_chunk`` cuts the horizon and the width after sampling."""
        return _checkpoint_fields(config.base_model_path)["action_horizon"], config.max_action_dim

    def action_targets(self, batch: dict[str, Tensor]) -> Tensor:
        """The pre-processor's padded chunk, zero where its ``action_mask`` is zero (the padded width, steps past an
        episode's end)."""
        return batch[ACTION] * batch["action_mask"].to(batch[ACTION].dtype)

    def action_weights(self, batch: dict[str, Tensor]) -> Tensor:
        """The pre-processor's ``action_mask``: GR00T's loss weighs the padding out, and so does the objective
        (:class:`snapflow.protocol.PaddedActions`), so the padding's velocity stays as free as GR00T leaves it. A
        batch without actions carries the checkpoint processor's mask of the horizon alone (B, horizon): every width
        of a step it keeps."""
        mask = batch["action_mask"]
        return mask if mask.ndim == 3 else mask[..., None]

    @classmethod
    def training_time_sampler(cls, config: Any) -> BetaTimeSampler:
        """GR00T's times in snapflow's direction: its t = noise_s (1 - u), u ~ Beta(alpha, 1), is snapflow's
        1 - noise_s + noise_s u (Beta(1.5, 1) from 0.001, as pi0's, at GR00T N1.7's defaults)."""
        fields = _checkpoint_fields(config.base_model_path)
        if fields["noise_beta_beta"] != 1.0:
            raise InvalidInputError(
                f"this groot samples times from Beta({fields['noise_beta_alpha']}, {fields['noise_beta_beta']}); "
                "snapflow samples Beta(a, 1) only"
            )
        # rounded: 1 - 0.999 is 0.0010000000000000009 in floating point
        return BetaTimeSampler(concentration=fields["noise_beta_alpha"], min_time=round(1.0 - fields["noise_s"], 12))

    def model_inputs(self, batch: dict[str, Tensor]) -> tuple[Any, ...]:
        """What GrootPolicy's ``predict_action_chunk`` hands its model's ``get_action``: the backbone's inputs and
        the action head's (state, embodiment), on the model's device and in its dtype, as plain dicts."""
        model = self.policy._groot_model
        if batch["pixel_values"].ndim == 3:  # rows lead (:meth:`example_observation`): laid out as the pre-processor
            batch = {**batch, **{key: batch[key].flatten(0, 1) for key in ("pixel_values", "image_grid_thw")}}
        inputs = self.policy._filter_groot_inputs(batch, include_action=False)
        return tuple(dict(part) for part in model.prepare_input(inputs))

    def encode_inputs(self, backbone_inputs: dict[str, Any], action_inputs: dict[str, Any]) -> dict[str, Any]:
        model = self.policy._groot_model
        with self.prefix_pass(model), self.autocast():
            return self._prefix(model.backbone(backbone_inputs), action_inputs)

    def autocast(self) -> torch.autocast:
        """bfloat16 autocast where the config says ``use_bf16`` (LeRobot's default), as GR00T's own forward and
        sampling run; off otherwise."""
        device = next(self.head.parameters()).device.type
        return torch.autocast(device_type=device, dtype=torch.bfloat16, enabled=self.policy.config.use_bf16)

    def _prefix(self, backbone_output: Any, action_inputs: Any) -> dict[str, Tensor]:
        """The action head's part of the prefix (VL layer norm and self-attention, the state encoder) after the
        backbone's ``backbone_output``, and what each step reads of it."""
        from transformers.feature_extraction_utils import BatchFeature

        backbone_output, action_inputs = BatchFeature(dict(backbone_output)), BatchFeature(dict(action_inputs))
        features = self.head._encode_features(backbone_output, action_inputs)
        return {
            "backbone_features": features["backbone_features"],
            "state_features": features["state_features"],
            "embodiment_id": action_inputs["embodiment_id"],
            "image_mask": backbone_output["image_mask"],
            "backbone_attention_mask": backbone_output["backbone_attention_mask"],
        }

    def denoise(self, context: dict[str, Any], x_t: Tensor, timestep: Tensor) -> Tensor:
        """GR00T's loop body (``get_action_with_features``) at snapflow's time t, GR00T's bucket of 1 - t."""
        with self.autocast():
            return self._velocity(context, x_t, *split_timestep(timestep)).to(x_t.dtype)

    def _velocity(self, context: dict[str, Any], x_t: Tensor, t: Tensor, s: Tensor) -> Tensor:
        head, embodiment = self.head, context["embodiment_id"]
        # GR00T trains and samples on whole buckets only: the sinusoids' fastest channels never saw a fraction
        bucket = torch.floor((1 - t) * head.num_timestep_buckets + BUCKET_ROUNDING)
        action_features = head.action_encoder(x_t, bucket, embodiment)
        if head.config.add_pos_embed:
            positions = torch.arange(action_features.shape[1], dtype=torch.long, device=x_t.device)
            action_features = action_features + head.position_embedding(positions).unsqueeze(0)
        tokens = torch.cat((context["state_features"], action_features), dim=1)
        masks = (
            {"image_mask": context["image_mask"], "backbone_attention_mask": context["backbone_attention_mask"]}
            if head.config.use_alternate_vl_dit
            else {}
        )
        output = head.model(
            hidden_states=tokens,
            encoder_hidden_states=context["backbone_features"],
            timestep=torch.stack([bucket, s], dim=1),
            **masks,
        )
        return -head.action_decoder(output, embodiment)[:, -x_t.shape[1] :]

    def draw_noise(self, context: dict[str, Any], batch_size: int) -> Tensor:
        """GR00T's own draw: a standard normal in the prefix features' dtype, after the prefix."""
        features = context["backbone_features"]
        return torch.randn((batch_size, *self.action_shape), dtype=features.dtype, device=features.device)

    def example_observation(self, device: torch.device) -> dict[str, Tensor]:
        """GR00T's own pre-processor's batch of one random frame (its Qwen3-VL processor sets the image tokens), its
        patches (flattened over the batch by the pre-processor) under a leading row axis, which :meth:`model_inputs`
        reads too (:func:`groot_processors`)."""
        config = self.policy.config
        widths = {OBS_STATE: config.robot_state_feature.shape, ACTION: config.action_feature.shape}
        stats = {key: {"min": -torch.ones(shape), "max": torch.ones(shape)} for key, shape in widths.items()}
        preprocessor, _ = groot_processors(self.policy, stats)
        frame = {key: torch.rand(1, *feature.shape) for key, feature in config.image_features.items()}
        batch = preprocessor({**frame, OBS_STATE: torch.randn(1, *widths[OBS_STATE]), "task": ["perform the task"]})
        # the image patches get a leading row, so that a batch of this frame repeated is its rows repeated
        images = {key: batch[key][None] for key in ("pixel_values", "image_grid_thw")}
        return {key: value.to(device) for key, value in {**batch, **images}.items() if torch.is_tensor(value)}

    def install_sampler(self, sample: ChunkSampler) -> None:
        from transformers.feature_extraction_utils import BatchFeature

        def get_action(backbone_output: Any, action_input: Any, options: dict[str, Any] | None = None) -> Any:
            if options is not None:
                raise InvalidInputError(
                    "GR00T's own real-time chunking (a previous chunk's overlap) is not one of snapflow's sampling "
                    "modes; sample this groot policy without rtc_config"
                )
            with torch.no_grad():
                chunk = sample((), context=self._prefix(backbone_output, action_input))
            return BatchFeature({"action_pred": chunk})

        self.head.get_action = get_action


def groot_processors(policy: nn.Module, dataset_stats: dict[str, dict[str, Tensor]]) -> tuple[Any, Any]:
    """LeRobot's pre- and post-processors of the GrootPolicy ``policy`` with ``dataset_stats``, their Qwen3-VL step
    reading the processor files of the backbone its checkpoint names (LeRobot's step names the hub's Cosmos-Reason2
    whatever the checkpoint's backbone)."""
    from lerobot.policies.groot.processor_groot import GrootN17VLMEncodeStep, make_groot_pre_post_processors

    preprocessor, postprocessor = make_groot_pre_post_processors(policy.config, dataset_stats=dataset_stats)
    for step in preprocessor.steps:
        if isinstance(step, GrootN17VLMEncodeStep):
            step.model_name = policy._groot_model.config.model_name
    return preprocessor, postprocessor


__all__ = ["GrootFlowPolicy", "groot_processors"]
