"""LeRobot's XVLAPolicy under SnapFlow (LeRobot >= 0.5).

X-VLA encodes the images and the instruction once, through Florence-2's encoder (``forward_vlm``); then each step its
soft-prompted transformer reads the noisy chunk, the state and a sinusoid of t, concatenated per action token and
projected by ``transformer.action_encoder``, and predicts the *clean* chunk a_hat. On LeRobot's path (t = 1 noise,
t = 0 data, x_t = t * noise + (1 - t) * a) that prediction is the velocity v = (x_t - a_hat) / t, which the objective
and the solver read; phi_s(s) is added to ``action_encoder``'s output.

X-VLA's own sampler is not Euler: each step it re-noises its latest a_hat with the first noise. Its one step equals
the naive one here (a_hat at t = 1), and its N steps are another discretisation of the same flow than ``teacher-N``
(Euler on v, which is DDIM on a_hat); the student keeps X-VLA's own loop out, so every mode is snapflow's.
"""

from __future__ import annotations

import functools
from pathlib import Path
from typing import Any

import torch
from torch import Tensor, nn

from snapflow.adapters.lerobot.base import ChunkSampler, LeRobotFlowPolicy, modeling_module, split_timestep
from snapflow.adapters.lerobot.smolvlm import feature_widths
from snapflow.adapters.lerobot_config import SmolVLMSize
from snapflow.flow.path import broadcast_time
from snapflow.flow.time_sampling import BetaTimeSampler
from snapflow.nn.time_embedding import TargetTimeEmbedding

#: the least flow-matching time distillation trains on: X-VLA weighs its clean-chunk error alike at every t, and the
#: velocity's error is that error over t, so times near 0 would outweigh all others (1 / t^2: 400 at this bound)
XVLA_MIN_TIME = 0.05
#: the action width LeRobot's X-VLA LIBERO post-processor reads: position 3, 6-D rotation 6, gripper 1
XVLA_LIBERO_ACTION_WIDTH = 10


def _transformer_with_target_time(
    transformer: nn.Module,
    target_time_embedding: nn.Module,
    domain_id: Tensor,
    vlm_features: Tensor,
    aux_visual_inputs: Tensor,
    action_with_noise: Tensor,
    proprio: Tensor,
    t: Tensor,
) -> Tensor:
    """X-VLA's ``SoftPromptedTransformer.forward`` with phi_s(s) added to the action tokens after
    ``action_encoder``; ``t`` (B,) reads as s = t, (B, 2) as [t, s]."""
    t, s = split_timestep(t)
    batch_size, num_actions = action_with_noise.shape[:2]
    time_tokens = modeling_module(transformer).timestep_embedding(t, transformer.dim_time)
    tokens = torch.cat(
        [
            action_with_noise,
            proprio.unsqueeze(1).expand(batch_size, num_actions, proprio.shape[-1]),
            time_tokens.unsqueeze(1).expand(batch_size, num_actions, transformer.dim_time),
        ],
        dim=-1,
    )
    x = transformer.action_encoder(tokens, domain_id)
    x = x + target_time_embedding(s).to(x.dtype)[:, None, :]
    if transformer.use_hetero_proj:
        visual = [
            transformer.vlm_proj(vlm_features, domain_id),
            transformer.aux_visual_proj(aux_visual_inputs, domain_id),
        ]
    else:
        visual = [transformer.vlm_proj(vlm_features), transformer.aux_visual_proj(aux_visual_inputs)]
    x = torch.cat([x, *visual], dim=1)
    if x.shape[1] > transformer.pos_emb.shape[1]:
        raise ValueError(f"X-VLA's sequence of {x.shape[1]} tokens exceeds max_len_seq={transformer.pos_emb.shape[1]}")
    x = x + transformer.pos_emb[:, : x.shape[1], :]
    if transformer.len_soft_prompts > 0:
        prompts = transformer.soft_prompt_hub(domain_id).view(
            batch_size, transformer.len_soft_prompts, transformer.hidden_size
        )
        x = torch.cat([x, prompts], dim=1)
    for block in transformer.blocks:
        x = block(x)
    return transformer.action_decoder(transformer.norm(x[:, :num_actions]), domain_id)


def _capturable_forward_vlm(
    model: nn.Module, input_ids: Tensor, pixel_values: Tensor, image_mask: Tensor
) -> dict[str, Tensor]:
    """X-VLA's ``forward_vlm`` without host synchronisations, so that one graph holds it (``deploy``, ONNX): X-VLA
    counts the valid camera views by ``.item()`` and gathers them by a boolean mask; here every view goes through
    the image encoder and a padded one's features are zeroed after, as X-VLA leaves them. With every view valid
    (each camera the policy reads present) the same passes run on the same rows, bit for bit."""
    batch, views = pixel_values.shape[:2]
    features = model.vlm.get_image_features(pixel_values.flatten(0, 1)).pooler_output
    features = features.view(batch, views, *features.shape[1:])
    features = torch.where(image_mask.view(batch, views, 1, 1).bool(), features, torch.zeros_like(features))
    # the primary view's tokens before the instruction's, every token attending to every other, as X-VLA's
    embeddings = torch.cat([features[:, 0], model.vlm.get_input_embeddings()(input_ids)], dim=1)
    attention = torch.ones(embeddings.shape[:2], dtype=torch.long, device=embeddings.device)
    encoded = model.vlm.language_model.encoder(attention_mask=attention, inputs_embeds=embeddings)[0]
    return {"vlm_features": encoded, "aux_visual_inputs": features[:, 1:].reshape(batch, -1, features.shape[-1])}


class XVLAFlowPolicy(LeRobotFlowPolicy):
    """SnapFlow view of a LeRobot ``XVLAPolicy``: Florence-2's encoder is the frozen prefix, the soft-prompted
    transformer the action expert."""

    policy_type = "xvla"
    steps_field = "num_denoising_steps"
    minimum_lerobot = "0.5"
    # X-VLA's encoder attends to every prompt token, padding included: cutting it would change the chunk
    masks_prompt_padding = False

    @classmethod
    def scratch_config(
        cls, vlm: Path, input_features: dict[str, Any], output_features: dict[str, Any], size: SmolVLMSize, **sizes: Any
    ) -> Any:
        """X-VLA over a Florence-2 at the SmolVLM size's widths: a four-stage DaViT whose third stage has the vision
        tower's width and depth, BART's encoder at the text tower's (its decoder, which X-VLA never runs, one layer),
        the soft-prompted transformer as wide and deep as the text tower; the SmolVLM folder's tokenizer; frames read
        at the size's image size, as SmolVLA reads them; state and action padded to no more than their own widths
        (``auto`` action space)."""
        from lerobot.policies.xvla.configuration_xvla import XVLAConfig
        from transformers import AutoTokenizer

        width, heads, text = size.vision_hidden, size.vision_heads, size.text_hidden
        vision = dict(
            depths=[1, 1, size.vision_layers, 1],
            embed_dim=[width // 4, width // 2, width, width],
            num_heads=[1, 2, heads, heads],
            num_groups=[1, 2, heads, heads],
            window_size=4,
            projection_dim=text,
            drop_path_rate=0.0,
        )
        attention_heads = dict(encoder_attention_heads=size.text_heads, decoder_attention_heads=size.text_heads)
        ffn = size.text_intermediate or 2 * text
        language = dict(
            d_model=text,
            encoder_layers=size.text_layers,
            decoder_layers=1,
            encoder_ffn_dim=ffn,
            decoder_ffn_dim=ffn,
            vocab_size=len(AutoTokenizer.from_pretrained(vlm)),
            max_position_embeddings=size.max_positions,
            **attention_heads,
        )
        state_width, action_width = feature_widths(input_features, output_features)
        return XVLAConfig(
            florence_config={"vision_config": vision, "text_config": language},
            max_state_dim=state_width,
            max_action_dim=action_width,
            tokenizer_name=str(vlm),
            resize_imgs_with_padding=(size.image_size, size.image_size),
            hidden_size=text,
            depth=size.text_layers,
            num_heads=size.text_heads,
            num_domains=1,
            len_soft_prompts=8,
            action_mode="auto",
            device="cpu",
            push_to_hub=False,
            input_features=input_features,
            output_features=output_features,
            **sizes,
        )

    def new_target_time_embedding(self) -> TargetTimeEmbedding:
        return TargetTimeEmbedding(self.policy.model.transformer.hidden_size)

    def install_target_time(self, model: nn.Module) -> None:
        # bound to phi_s itself, not to the model that holds both: no module cycle, and .to() / loading keep it
        model.transformer.forward = functools.partial(
            _transformer_with_target_time, model.transformer, model.target_time_embedding
        )

    def expert_modules(self) -> list[nn.Module]:
        return [self.policy.model.transformer]

    @classmethod
    def chunk_shape(cls, config: Any) -> tuple[int, int]:
        """X-VLA's action space's width: ``max_action_dim`` for ``auto``, the named space's own otherwise."""
        from lerobot.policies.xvla.action_hub import build_action_space

        mode = config.action_mode.lower()
        width = config.max_action_dim if mode == "auto" else build_action_space(mode).dim_action
        return config.chunk_size, width

    def action_targets(self, batch: dict[str, Tensor]) -> Tensor:
        return self.policy._prepare_action_targets(batch)

    def loss_cuts_padded_width(self) -> bool:
        """``auto``'s loss is on the dataset's width alone; a named space's chunk is its own width, no padding."""
        return self.policy.config.action_mode.lower() == "auto"

    @classmethod
    def env_processors(cls, env_config: Any, config: Any) -> tuple[Any, Any]:
        """LeRobot hands every X-VLA the pipeline of its pretrained LIBERO checkpoint: ImageNet normalisation and a
        domain id, then 10-D end-effector actions whose 6-D rotation becomes axis-angle. A policy of the dataset's
        own narrower actions (LIBERO's 7-D, as one trained from scratch here) takes the environment's own
        processors, as every other type: its own pre-processor normalises its images and sets its domain, which
        LeRobot's pipeline would do twice (LeRobot issue #2955), and no rotation is there to convert."""
        if config.action_feature.shape[0] >= XVLA_LIBERO_ACTION_WIDTH:
            return super().env_processors(env_config, config)
        return env_config.get_env_processors()

    @classmethod
    def training_time_sampler(cls, config: Any) -> BetaTimeSampler:
        """Uniform times, as X-VLA trains, from :data:`XVLA_MIN_TIME` up."""
        return BetaTimeSampler(concentration=1.0, min_time=XVLA_MIN_TIME)

    def model_inputs(self, batch: dict[str, Tensor]) -> tuple[Any, ...]:
        inputs = self.policy._build_model_inputs(batch)
        return tuple(inputs[name] for name in ("input_ids", "image_input", "image_mask", "domain_id", "proprio"))

    def encode_inputs(
        self, input_ids: Tensor, image_input: Tensor, image_mask: Tensor, domain_id: Tensor, proprio: Tensor
    ) -> dict[str, Any]:
        model = self.policy.model
        dtype = model._get_target_dtype()
        with self.prefix_pass(model.vlm):
            encoded = _capturable_forward_vlm(model, input_ids, image_input.to(dtype), image_mask)
        return {**encoded, "domain_id": domain_id, "proprio": proprio.to(dtype)}

    def denoise(self, context: dict[str, Any], x_t: Tensor, timestep: Tensor) -> Tensor:
        model = self.policy.model
        proprio, noisy = model.action_space.preprocess(context["proprio"], x_t)
        clean = model.transformer(
            domain_id=context["domain_id"],
            vlm_features=context["vlm_features"],
            aux_visual_inputs=context["aux_visual_inputs"],
            action_with_noise=noisy,
            proprio=proprio,
            t=timestep.to(x_t.dtype),
        )
        return (x_t - clean) / broadcast_time(split_timestep(timestep)[0], x_t)

    def draw_noise(self, context: dict[str, Any], batch_size: int) -> Tensor:
        """X-VLA's own draw: a standard normal in the model's dtype, after the prefix pass, so that a seeded chunk
        starts from the noise X-VLA's sampler would."""
        features = context["vlm_features"]
        return torch.randn((batch_size, *self.action_shape), device=features.device, dtype=features.dtype)

    def install_sampler(self, sample: ChunkSampler) -> None:
        model = self.policy.model

        def generate_actions(
            input_ids: Tensor, image_input: Tensor, image_mask: Tensor, domain_id: Tensor, proprio: Tensor, **_: Any
        ) -> Tensor:
            # X-VLA's own steps (config.num_denoising_steps) give way to the sampling mode's
            with torch.no_grad():
                chunk = sample((input_ids, image_input, image_mask, domain_id, proprio))
            return model.action_space.postprocess(chunk)

        model.generate_actions = generate_actions


__all__ = ["XVLAFlowPolicy", "XVLA_MIN_TIME"]
