"""LeRobot's VLAJEPAPolicy (VLA-JEPA) under SnapFlow (LeRobot >= 0.6.1).

VLA-JEPA encodes the observation once: Qwen3-VL reads the cameras and a prompt built from the task, which the policy
tokenizes itself, and its last decoder layer's states at the prompt's ``<|embodied_action|>`` tokens are the
conditioning tokens; the action head's state encoder makes the state one more token (``_build_inputs``): the frozen
prefix. Each step its action encoder reads the noisy chunk and the time, learned future tokens and position
embeddings join it, a DiT cross-attends to the conditioning tokens (every other block) and the action decoder gives
the velocity: the action expert.

Its flow runs the other way from snapflow's (t = 0 noise, t = 1 data, velocity data - noise): snapflow's time is
1 - t and its velocity the negative of VLA-JEPA's. Its time enters as a bucket, int(1000 t), into the action
encoder's sinusoid and the DiT's ``timestep_encoder``, whose output drives every block's adaptive layer norm and the
output modulation; phi_s(s) is added to that output, as GR00T's. It trains on t = (0.999 - u) / 0.999, u ~ Beta(1.5,
1) (:class:`VLAJEPATimeSampler`), from standard-normal noise, its loss a mean over the steps before an episode's end,
and it integrates 4 Euler steps a chunk.

Its JEPA world model (a frozen V-JEPA 2 video encoder and an action-conditioned predictor of the next frames'
embeddings, read from Qwen's ``<|action_i|>`` tokens) is a training-time loss that shapes Qwen: the action head never
reads it, and sampling never runs it. The student keeps its weights and never runs it either.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Any

import torch
import torch.nn.functional as F  # noqa: N812
from torch import Tensor, nn

from snapflow.adapters.lerobot.base import ACTION, OBS_STATE, ChunkSampler, LeRobotFlowPolicy, split_timestep
from snapflow.errors import InvalidInputError
from snapflow.nn.time_embedding import TargetTimeEmbedding

#: what makes snapflow's float32 grid land on VLA-JEPA's own buckets (1 - 0.7 is 0.29999998 in float32, a bucket
#: below its int(1000 * 3 / 10) without it), while no bucket moves by more than a 1000th of itself
BUCKET_ROUNDING = 1e-3


@dataclass(frozen=True)
class VLAJEPATimeSampler:
    """VLA-JEPA's training times in snapflow's direction: its t = (noise_s - u) / noise_s, u ~ Beta(concentration,
    1), is snapflow's u / noise_s, drawn from the caller's generator by inverting Beta(a, 1)'s CDF. With noise_s =
    0.999 a draw may pass 1 by up to a 1000th (VLA-JEPA's t below 0), as VLA-JEPA's own draws do."""

    concentration: float = 1.5
    noise_s: float = 0.999

    def __call__(
        self, batch_size: int, *, device: torch.device | str = "cpu", generator: torch.Generator | None = None
    ) -> Tensor:
        u = torch.rand(batch_size, device=device, generator=generator).pow(1 / self.concentration)
        return u / self.noise_s


def _timestep_encoder_with_target_time(
    encoder: nn.Module, target_time_embedding: nn.Module, buckets: int, timestep: Tensor
) -> Tensor:
    """The DiT's ``TimestepEncoder.forward`` with phi_s(s) added to its output. LeRobot's own (B,) timestep is
    VLA-JEPA's bucket b, read as s = 1 - b / buckets (snapflow's t); the adapter's (B, 2) is [bucket, snapflow's s]."""
    bucket, s = (timestep, 1 - timestep / buckets) if timestep.ndim == 1 else timestep.unbind(dim=1)
    embedding = type(encoder).forward(encoder, bucket)
    return embedding + target_time_embedding(s).to(embedding.dtype)


class VLAJEPAFlowPolicy(LeRobotFlowPolicy):
    """SnapFlow view of a LeRobot ``VLAJEPAPolicy``: Qwen3-VL and the state encoder are the frozen prefix; the action
    encoder, the future tokens, the position embedding, the DiT and the action decoder the action expert."""

    policy_type = "vla_jepa"
    steps_field = "num_inference_timesteps"
    minimum_lerobot = "0.6.1"
    # VLA-JEPA builds and tokenizes its prompt from the task's text itself, inside the prefix
    masks_prompt_padding = False
    export_refusal = (
        "VLA-JEPA builds its Qwen3-VL prompt from the task's text (strings) with Qwen's processor inside its prefix "
        "pass, on the host, so no graph of tensors from the batch to the chunk exists for torch.export to trace"
    )

    def __init__(self, policy: nn.Module) -> None:
        super().__init__(policy)
        self.training_time_sampler(policy.config)  # refuses, by name, times snapflow cannot sample

    @property
    def head(self) -> nn.Module:
        """VLA-JEPA's action head: the state encoder (prefix) and the action expert."""
        return self.policy.model.action_model

    @property
    def time_owner(self) -> nn.Module:
        return self.head.model

    def new_target_time_embedding(self) -> TargetTimeEmbedding:
        return TargetTimeEmbedding(self.head.model.inner_dim)

    def install_target_time(self, model: nn.Module) -> None:
        # bound to phi_s itself, not to the policy that holds both: no module cycle
        encoder, buckets = model.timestep_encoder, self.policy.config.action_num_timestep_buckets
        encoder.forward = functools.partial(
            _timestep_encoder_with_target_time, encoder, model.target_time_embedding, buckets
        )

    def expert_modules(self) -> list[nn.Module]:
        head = self.head
        return [head.action_encoder, head.future_tokens, head.position_embedding, head.model, head.action_decoder]

    @classmethod
    def chunk_shape(cls, config: Any) -> tuple[int, int]:
        """VLA-JEPA's own noise: ``chunk_size`` by the robot's ``action_dim``, no padding."""
        return config.chunk_size, config.action_dim

    @classmethod
    def training_time_sampler(cls, config: Any) -> VLAJEPATimeSampler:
        """VLA-JEPA's times (``sample_time``) in snapflow's direction (:class:`VLAJEPATimeSampler`)."""
        if config.action_noise_beta_beta != 1.0:
            raise InvalidInputError(
                f"this vla_jepa samples times from Beta({config.action_noise_beta_alpha}, "
                f"{config.action_noise_beta_beta}); snapflow samples Beta(a, 1) only"
            )
        return VLAJEPATimeSampler(config.action_noise_beta_alpha, config.action_noise_s)

    def action_targets(self, batch: dict[str, Tensor]) -> Tensor:
        """The batch's chunk, its last ``chunk_size`` steps, as VLA-JEPA's training forward reads it."""
        return batch[ACTION][:, -self.policy.config.chunk_size :].float()

    def action_weights(self, batch: dict[str, Tensor]) -> Tensor | None:
        """1 before an episode's end and 0 past it (``action_is_pad``): VLA-JEPA's loss is the mean over those steps
        (:class:`snapflow.protocol.PaddedActions`); None where the batch marks no padding."""
        padding = batch.get("action_is_pad")
        if padding is None:
            return None
        return (~padding[:, -self.policy.config.chunk_size :])[..., None].float()

    def model_inputs(self, batch: dict[str, Tensor]) -> tuple[Any, ...]:
        """What VLAJEPAPolicy's ``predict_action_chunk`` hands its model (``_prepare_model_inputs``: the current
        frame of a camera's frames, the tasks, the current state as (B, 1, D)), the cameras as one (B, C, H, W) tensor
        each. One task for a batch of several observations (a frame repeated, as bench repeats it) is every row's."""
        inputs = self.policy._prepare_model_inputs(batch, training=False)
        cameras = [torch.stack(views) for views in zip(*inputs["images"], strict=True)]
        tasks = inputs["instructions"]
        tasks = tasks * cameras[0].shape[0] if len(tasks) == 1 else tasks
        return cameras, tasks, inputs.get("state")

    def encode_inputs(self, cameras: list[Tensor], tasks: list[str], state: Tensor | None) -> dict[str, Tensor]:
        model = self.policy.model
        size = model.config.resize_images_to
        if size is not None:  # as VLAJEPAModel.predict_action resizes them
            cameras = [F.interpolate(camera, size=tuple(size), mode="area") for camera in cameras]
        images = [list(views) for views in zip(*cameras, strict=True)]
        with self.prefix_pass(model):
            tokens, _ = model._encode_qwen(images, tasks, need_action_tokens=False)
            return self._prefix(tokens, state)

    def _prefix(self, tokens: Tensor, state: Tensor | None) -> dict[str, Tensor]:
        """The conditioning tokens in float32, as VLA-JEPA's sampler reads them, and the state's token."""
        context = {"tokens": tokens.float()}
        if state is not None and self.head.state_encoder is not None:
            context["state"] = self.head.state_encoder(state.float().reshape(state.shape[0], 1, -1))
        return context

    def denoise(self, context: dict[str, Tensor], x_t: Tensor, timestep: Tensor) -> Tensor:
        """VLA-JEPA's velocity at snapflow's time t, its bucket of 1 - t, in float32 without autocast: VLA-JEPA runs
        its action head under an autocast to float32, which turns autocast off."""
        with torch.autocast(x_t.device.type, enabled=False):
            return self._velocity(context, x_t.float(), *split_timestep(timestep)).to(x_t.dtype)

    def _velocity(self, context: dict[str, Tensor], x_t: Tensor, t: Tensor, s: Tensor) -> Tensor:
        head, size, length = self.head, x_t.shape[0], x_t.shape[1]
        # whole buckets, truncated as VLA-JEPA's .long() truncates its own (a time past 1 is its bucket 0)
        bucket = ((1 - t.float()) * self.policy.config.action_num_timestep_buckets + BUCKET_ROUNDING).long()
        actions = head.action_encoder(x_t, bucket)
        actions = actions + head.position_embedding(torch.arange(length, device=x_t.device))[None]
        sequence = [head.future_tokens.weight.unsqueeze(0).expand(size, -1, -1), actions]
        if "state" in context:
            sequence.insert(0, context["state"])
        output = head.model(
            hidden_states=torch.cat(sequence, dim=1),
            encoder_hidden_states=context["tokens"],
            timestep=torch.stack([bucket.float(), s.float()], dim=1),
        )
        return -head.action_decoder(output[:, -length:])

    def example_observation(self, device: torch.device) -> dict[str, Any]:
        """A batch-1 observation as VLA-JEPA's pre-processor hands it to the model: its cameras in [0, 1], its
        normalised state, and the task as text (VLA-JEPA builds its prompt itself)."""
        config = self.policy.config
        observation: dict[str, Any] = {
            key: torch.rand(1, *feature.shape, device=device) for key, feature in config.image_features.items()
        }
        if config.robot_state_feature is not None:
            observation[OBS_STATE] = torch.randn(1, *config.robot_state_feature.shape, device=device)
        observation["task"] = ["perform the task"]
        return observation

    def install_sampler(self, sample: ChunkSampler) -> None:
        def predict_action(conditioning_tokens: Tensor, state: Tensor | None = None) -> Tensor:
            with torch.no_grad():
                return sample((), context=self._prefix(conditioning_tokens, state))

        self.head.predict_action = predict_action


__all__ = ["BUCKET_ROUNDING", "VLAJEPAFlowPolicy", "VLAJEPATimeSampler"]
