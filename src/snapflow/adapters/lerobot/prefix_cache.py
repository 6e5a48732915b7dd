"""The pi0 family's layout under SnapFlow: LeRobot's pi0, pi0.5 and SmolVLA all run ``embed_prefix`` -> one VLM pass
that fills a key/value cache -> ``denoise_step(..., x_t, timestep)`` per Euler step, embed the time inside
``embed_suffix`` and sample through ``model.sample_actions``. A subclass names the layer phi_s(s) is added to and its
``embed_suffix`` rewritten to read [t, s]."""

from __future__ import annotations

import types
from collections.abc import Callable
from typing import Any, ClassVar

from torch import Tensor, nn
from transformers import DynamicCache  # here, not in the pass: torch.compile breaks its graph at an import

from snapflow.adapters.lerobot.base import ChunkSampler, LeRobotFlowPolicy
from snapflow.nn.time_embedding import TargetTimeEmbedding


def cache_tensors(cache: Any) -> Any:
    """The prefix cache as plain tensors, so the objective can select batch rows from it.

    LeRobot 0.4.4's SmolVLA keeps a dict of dicts of tensors; newer LeRobot returns a transformers
    ``DynamicCache``, kept here as one (keys, values) pair per layer.
    """
    return cache if isinstance(cache, dict) else tuple((keys, values) for keys, values, *_ in cache)


def cache_for_one_pass(tensors: Any) -> Any:
    """A fresh cache object over the prefix tensors for a single ``denoise_step``.

    ``denoise_step`` appends the suffix to its cache (and SmolVLA crops it back in place): a cache shared
    between the no-grad teacher passes and the gradient pass would silently hand the latter detached state.
    """
    if isinstance(tensors, dict):
        return {layer: dict(entry) for layer, entry in tensors.items()}
    return DynamicCache(tensors)


class PrefixCacheFlowPolicy(LeRobotFlowPolicy):
    """A LeRobot policy of the pi0 family: its context is ``{"cache", "prefix_pad_masks", ...}``."""

    #: the layer whose output phi_s(s) is added to (before the SiLU that follows it)
    time_fusion_layer: ClassVar[str]
    #: the policy's ``embed_suffix`` rewritten to read [t, s]; bound to the LeRobot model instance
    embed_suffix_with_target_time: ClassVar[Callable[..., Any]]

    def new_target_time_embedding(self) -> TargetTimeEmbedding:
        model = self.policy.model
        fusion = getattr(model, self.time_fusion_layer)
        return TargetTimeEmbedding(
            fusion.out_features, min_period=model.config.min_period, max_period=model.config.max_period
        )

    def install_target_time(self, model: nn.Module) -> None:
        model.embed_suffix = types.MethodType(type(self).embed_suffix_with_target_time, model)

    def draw_noise(self, context: dict[str, Any], batch_size: int) -> Tensor:
        """LeRobot's own ``sample_noise``, so that a seeded chunk is the one LeRobot draws."""
        return self.policy.model.sample_noise((batch_size, *self.action_shape), context["prefix_pad_masks"].device)

    def install_sampler(self, sample: ChunkSampler) -> None:
        def sample_actions(
            model: nn.Module,
            *inputs: Any,
            noise: Tensor | None = None,
            inference_delay: int | None = None,
            prev_chunk_left_over: Tensor | None = None,
            execution_horizon: int | None = None,
            **_: Any,
        ) -> Tensor:
            return sample(inputs, noise, inference_delay, prev_chunk_left_over, execution_horizon)

        self.policy.model.sample_actions = types.MethodType(sample_actions, self.policy.model)


__all__ = ["PrefixCacheFlowPolicy", "cache_for_one_pass", "cache_tensors"]
