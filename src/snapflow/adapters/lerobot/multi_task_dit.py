"""LeRobot's MultiTaskDiTPolicy under SnapFlow, trained with ``objective="flow_matching"`` (LeRobot >= 0.5).

Multi-task DiT encodes the observation once (CLIP's vision and text encoders and the state) into one conditioning
vector, the frozen prefix; its diffusion transformer, the action expert, then predicts the velocity from the noisy
chunk, the time's embedding (``time_mlp``) and that vector through adaptive layer norms. Its flow runs the other way
from snapflow's (t = 0 noise, t = 1 data): snapflow's time is 1 - t and its velocity the negative of the policy's.
phi_s(s) is added to ``time_mlp``'s output. By default it integrates 100 Euler steps a chunk, the most of any LeRobot
policy. Its DDPM objective (``objective="diffusion"``, the config's default) has no velocity and is refused by name.
"""

from __future__ import annotations

import functools
from typing import Any

import torch
from torch import Tensor, nn

from snapflow.adapters.lerobot.base import ACTION, OBS_STATE, ChunkSampler, LeRobotFlowPolicy, split_timestep
from snapflow.errors import InvalidInputError
from snapflow.flow.time_sampling import BetaTimeSampler
from snapflow.nn.time_embedding import TargetTimeEmbedding


def _noise_predictor_with_target_time(
    predictor: nn.Module, target_time_embedding: nn.Module, x: Tensor, timestep: Tensor, conditioning_vec: Tensor
) -> Tensor:
    """Multi-task DiT's ``DiffusionTransformer.forward`` with phi_s(s) added to ``time_mlp``'s output. LeRobot's own
    (B,) timestep is its time t, read as s = 1 - t (snapflow's); the adapter's (B, 2) is [LeRobot's t, snapflow's s]."""
    t, s = (timestep, 1 - timestep) if timestep.ndim == 1 else timestep.unbind(dim=1)
    time_features = predictor.time_mlp(t)
    time_features = time_features + target_time_embedding(s).to(time_features.dtype)
    conditioning = torch.cat([time_features, conditioning_vec], dim=-1)
    hidden = predictor.input_proj(x)
    if predictor.pos_embedding is not None:
        hidden = hidden + predictor.pos_embedding[:, : x.shape[1], :]
    for block in predictor.transformer_blocks:
        hidden = block(hidden, conditioning)
    return predictor.output_proj(hidden)


class MultiTaskDiTFlowPolicy(LeRobotFlowPolicy):
    """SnapFlow view of a LeRobot ``MultiTaskDiTPolicy`` trained by flow matching."""

    policy_type = "multi_task_dit"
    steps_field = "num_integration_steps"
    minimum_lerobot = "0.5"
    # CLIP's text encoder pools the token its config names by id: its padding is kept as the policy saw it
    masks_prompt_padding = False

    def __init__(self, policy: nn.Module) -> None:
        config = policy.config
        if config.objective != "flow_matching":
            raise InvalidInputError(
                f"this multi_task_dit policy was trained with objective={config.objective!r}: a DDPM denoiser has no "
                "velocity field to jump along; snapflow distils one trained with objective='flow_matching'"
            )
        if config.sigma_min != 0:
            raise InvalidInputError(
                f"this multi_task_dit policy's path keeps sigma_min={config.sigma_min} of noise at the data: snapflow "
                "distils the straight path from noise to data (sigma_min=0, the default)"
            )
        super().__init__(policy)

    @property
    def time_owner(self) -> nn.Module:
        return self.policy.noise_predictor

    def new_target_time_embedding(self) -> TargetTimeEmbedding:
        return TargetTimeEmbedding(self.policy.noise_predictor.timestep_embed_dim)

    def install_target_time(self, model: nn.Module) -> None:
        # bound to phi_s itself, not to the policy that holds both: no module cycle
        model.forward = functools.partial(_noise_predictor_with_target_time, model, model.target_time_embedding)

    def expert_modules(self) -> list[nn.Module]:
        return [self.policy.noise_predictor]

    @classmethod
    def chunk_shape(cls, config: Any) -> tuple[int, int]:
        return config.horizon, config.action_feature.shape[0]

    def action_targets(self, batch: dict[str, Tensor]) -> Tensor:
        return batch[ACTION]

    @classmethod
    def training_time_sampler(cls, config: Any) -> BetaTimeSampler:
        """The policy's own times in snapflow's direction: its t = s_max (1 - u), u ~ Beta(alpha, 1), is snapflow's
        1 - s_max + s_max u; uniform times stay uniform."""
        if config.timestep_sampling_strategy == "uniform":
            return BetaTimeSampler(concentration=1.0, min_time=0.0)
        if config.timestep_sampling_beta != 1.0:
            raise InvalidInputError(
                f"this multi_task_dit samples times from Beta({config.timestep_sampling_alpha}, "
                f"{config.timestep_sampling_beta}); snapflow samples Beta(a, 1) only"
            )
        return BetaTimeSampler(concentration=config.timestep_sampling_alpha, min_time=1.0 - config.timestep_sampling_s)

    def model_inputs(self, batch: dict[str, Tensor]) -> tuple[Any, ...]:
        """The batch as the policy's encoder reads it: with its observation-steps axis (a single frame's batch, as
        snapflow's evaluator and the pre-processor give it, is one step), cameras stacked."""
        policy = self.policy
        keys = [OBS_STATE, *policy.config.image_features]
        frames = {key: batch[key].unsqueeze(1) for key in keys if key in batch and _without_steps(key, batch[key])}
        if frames and policy.config.n_obs_steps != 1:
            raise InvalidInputError(
                f"this multi_task_dit reads {policy.config.n_obs_steps} observation steps; the batch holds one frame"
            )
        return (policy._prepare_batch({**batch, **frames}),)

    def encode_inputs(self, batch: dict[str, Tensor]) -> dict[str, Any]:
        encoder = self.policy.observation_encoder
        with self.prefix_pass(encoder):
            return {"conditioning": encoder.encode(batch)}

    def denoise(self, context: dict[str, Any], x_t: Tensor, timestep: Tensor) -> Tensor:
        t, s = split_timestep(timestep)
        ours = torch.stack([1 - t, s], dim=1).to(x_t.dtype)
        return -self.policy.noise_predictor(x_t, ours, conditioning_vec=context["conditioning"])

    def draw_noise(self, context: dict[str, Any], batch_size: int) -> Tensor:
        """The policy's own draw: a standard normal in the expert's dtype, after the observation is encoded."""
        parameter = next(self.policy.noise_predictor.parameters())
        return torch.randn((batch_size, *self.action_shape), dtype=parameter.dtype, device=parameter.device)

    def lone_chunk_batch(self, batch: dict[str, Tensor]) -> dict[str, Tensor]:
        """LeRobot's ``predict_action_chunk`` reads the observation from the queues its ``select_action`` fills: a
        call on its own (LeRobot's policy server) gets them filled with this one observation, as ``select_action``
        fills them at an episode's start. A policy of several observation steps has no history to stand on here."""
        from lerobot.policies.utils import populate_queues

        policy = self.policy
        queued = policy._queues[OBS_STATE] if policy._queues is not None else ()
        if queued and queued[-1] is batch.get(OBS_STATE):  # select_action queued this very observation
            return batch
        if policy.config.n_obs_steps != 1:
            raise InvalidInputError(
                f"this multi_task_dit reads {policy.config.n_obs_steps} observation steps; a chunk asked for one "
                "observation at a time (LeRobot's policy server) gives it one"
            )
        policy.reset()
        # as select_action, without the action a transition carries (None here): its queue is the chunk's
        prepared = policy._prepare_batch({key: value for key, value in batch.items() if key != ACTION})
        populate_queues(policy._queues, prepared)
        return prepared

    def install_sampler(self, sample: ChunkSampler) -> None:
        def conditional_sample(model: nn.Module, batch_size: int, conditioning_vec: Tensor) -> Tensor:
            return sample((), context={"conditioning": conditioning_vec})

        self.policy.objective.conditional_sample = conditional_sample


def _without_steps(key: str, tensor: Tensor) -> bool:
    """Whether a batch's ``key`` lacks the observation-steps axis: a state of (B, D), an image of (B, C, H, W)."""
    return tensor.ndim == (2 if key == OBS_STATE else 4)


__all__ = ["MultiTaskDiTFlowPolicy"]
