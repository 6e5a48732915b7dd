"""What every LeRobot flow-matching policy shares under SnapFlow.

LeRobot's pi0, pi0.5 and SmolVLA all run ``embed_prefix`` -> one VLM pass that fills a key/value cache ->
``denoise_step(..., x_t, timestep)`` per Euler step, and all embed the time inside ``embed_suffix``. The
adapter replaces ``embed_suffix`` on the model *instance* (LeRobot's files stay untouched) by one that reads
a timestep of shape (B, 2) as [t, s] and adds phi_s(s) where the policy's time embedding enters. A plain
(B,) timestep means s = t, so LeRobot's own ``forward`` and sampler keep running the flow-matching teacher.
s travels as an argument, never as hook state, so gradient checkpointing recomputes the same values.
"""

from __future__ import annotations

import contextlib
import sys
import types
from abc import ABC, abstractmethod
from collections.abc import Callable, Iterator
from typing import Any, ClassVar

import torch
from torch import Tensor, nn
from transformers import DynamicCache  # here, not in the pass: torch.compile breaks its graph at an import

from snapflow.adapters.lerobot.rtc import rtc_processor_in_force, sample_with_rtc
from snapflow.errors import InvalidInputError
from snapflow.flow.modes import SamplingMode
from snapflow.flow.time_sampling import BetaTimeSampler
from snapflow.nn.time_embedding import TargetTimeEmbedding

OBS_LANGUAGE_TOKENS = "observation.language.tokens"
OBS_LANGUAGE_ATTENTION_MASK = "observation.language.attention_mask"
#: a prompt cut of its padding keeps a multiple of this many tokens: a compiled prefix then meets few shapes
PROMPT_BUCKET = 16


def split_timestep(timestep: Tensor) -> tuple[Tensor, Tensor]:
    """(B,) -> (t, t), LeRobot's own calls; (B, 2) -> (t, s), the adapter's calls."""
    return (timestep, timestep) if timestep.ndim == 1 else timestep.unbind(dim=1)


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


@contextlib.contextmanager
def frozen_prefix_pass(vlm: nn.Module) -> Iterator[None]:
    """Run the frozen VLM's prefix pass without a graph and in eval mode (each module's mode restored after).

    Besides saving the graph, eval mode keeps the key/value cache when gradient checkpointing is on: Hugging Face
    models drop ``use_cache`` when they checkpoint in training mode.
    """
    modes = [(module, module.training) for module in vlm.modules()]
    vlm.eval()
    try:
        with torch.no_grad():
            yield
    finally:
        for module, training in modes:
            module.training = training


def modeling_module(model: nn.Module) -> types.ModuleType:
    """The LeRobot module that defines ``model``: its own helpers (sinusoid, masks) are used, whatever the
    LeRobot version moved them to. Read from ``sys.modules`` (the class is defined, so its module is loaded), which
    torch.compile traces through, where an import would break its graph."""
    return sys.modules[type(model).__module__]


def lerobot_time_sampler(config: Any) -> BetaTimeSampler:
    """The flow-matching times a LeRobot policy of ``config`` trains on, read from its config where LeRobot keeps
    them (pi0 / pi0.5: ``time_sampling_beta_alpha`` / ``_beta``); SmolVLA's code fixes Beta(1.5, 1). Every one
    shifts them into [0.001, 1]."""
    alpha = getattr(config, "time_sampling_beta_alpha", 1.5)
    beta = getattr(config, "time_sampling_beta_beta", 1.0)
    if beta != 1.0:
        raise InvalidInputError(
            f"this {config.type} samples times from Beta({alpha}, {beta}); snapflow samples Beta(a, 1) only"
        )
    return BetaTimeSampler(concentration=alpha, min_time=0.001)


class LeRobotFlowPolicy(nn.Module, ABC):
    """A LeRobot policy seen through :class:`snapflow.protocol.FlowPolicy`.

    Batches are what the policy's own pre-processor produces (normalised state, images in [0, 1], language
    tokens and mask). Actions are (B, chunk_size, max_action_dim), padded as ``policy.prepare_action`` pads them.
    Subclasses name where time enters and how the policy's prefix and denoising step are called.
    """

    policy_type: ClassVar[str]
    #: the layer whose output phi_s(s) is added to (before the SiLU that follows it)
    time_fusion_layer: ClassVar[str]
    #: the policy's ``embed_suffix`` rewritten to read [t, s]; bound to the LeRobot model instance
    embed_suffix_with_target_time: ClassVar[Callable[..., Any]]
    #: the oldest LeRobot release whose internals the adapter follows
    minimum_lerobot: ClassVar[str] = "0.4.4"
    #: what :func:`snapflow.inference.compile_policy` compiles: the prefix pass LeRobot's sampling calls (``encode``
    #: goes through it too) and the velocity
    compiled_methods: ClassVar[tuple[str, str]] = ("encode_inputs", "velocity")

    def __init__(self, policy: nn.Module) -> None:
        super().__init__()
        self.policy = policy
        #: the prefix pass keeps its graph (a teacher trained from scratch); distillation keeps the VLM frozen
        self.train_prefix = False
        model = policy.model
        if not hasattr(model, "target_time_embedding"):
            fusion = getattr(model, self.time_fusion_layer)
            embedding = TargetTimeEmbedding(
                fusion.out_features, min_period=model.config.min_period, max_period=model.config.max_period
            )
            model.target_time_embedding = embedding.to(fusion.weight.device)
            model.embed_suffix = types.MethodType(type(self).embed_suffix_with_target_time, model)

    @property
    def target_time_embedding(self) -> TargetTimeEmbedding:
        """phi_s, stored inside the LeRobot model so that LeRobot's own checkpoints carry it (registered once:
        safetensors refuses tensors saved under two names)."""
        return self.policy.model.target_time_embedding

    @abstractmethod
    def expert_modules(self) -> list[nn.Module]:
        """The action expert and its projections: what distillation trains besides phi_s."""

    def expert_parameters(self) -> list[nn.Parameter]:
        """What distillation trains, as in the paper: the action expert, its projections and phi_s; the VLM
        stays frozen."""
        modules = [*self.expert_modules(), self.target_time_embedding]
        return [parameter for module in modules for parameter in module.parameters()]

    def prefix_pass(self, vlm: nn.Module) -> contextlib.AbstractContextManager:
        """How the prefix runs: :func:`frozen_prefix_pass` unless ``train_prefix``, then as it is, with gradients;
        as it is too where it is frozen already (no gradients, the VLM in eval mode: deployment), which keeps a
        compiled prefix in one graph (torch.compile breaks its graph at a generator's context manager)."""
        if self.train_prefix or (not torch.is_grad_enabled() and not vlm.training):
            return contextlib.nullcontext()
        return frozen_prefix_pass(vlm)

    @abstractmethod
    def model_inputs(self, batch: dict[str, Tensor]) -> tuple[Any, ...]:
        """The positional inputs LeRobot's ``model.sample_actions`` receives before ``noise``."""

    @abstractmethod
    def encode_inputs(self, *inputs: Any) -> dict[str, Any]:
        """Prefix pass from :meth:`model_inputs`: images, instruction (and state) through the frozen VLM once,
        without gradients, keeping its key/value cache (as tensors) and the prefix padding mask."""

    @abstractmethod
    def denoise(self, context: dict[str, Any], x_t: Tensor, timestep: Tensor) -> Tensor:
        """One call of the policy's own ``denoise_step`` against a fresh cache over the context's prefix."""

    def encode(self, batch: dict[str, Tensor]) -> dict[str, Any]:
        return self.encode_inputs(*self.model_inputs(batch))

    def without_prompt_padding(self, batch: dict[str, Tensor], multiple: int = PROMPT_BUCKET) -> dict[str, Tensor]:
        """``batch`` with its prompt's right padding cut down to its longest prompt, rounded up to ``multiple``
        tokens. Padding is masked out of every attention and position ids count real tokens only, so the chunk is
        the same for fewer tokens through the VLM (LeRobot's pi0.5 pads every prompt to 200 tokens). A batch whose
        padding is not on the right is returned as it is."""
        mask = batch[OBS_LANGUAGE_ATTENTION_MASK]
        width = mask.shape[1]
        keep = min(width, -(-max(int(mask.sum(dim=1).max()), 1) // multiple) * multiple)
        if keep == width or bool(mask[:, keep:].any()):
            return batch
        return {
            **batch,
            OBS_LANGUAGE_TOKENS: batch[OBS_LANGUAGE_TOKENS][:, :keep],
            OBS_LANGUAGE_ATTENTION_MASK: mask[:, :keep],
        }

    def velocity(self, x_t: Tensor, t: Tensor, s: Tensor, context: dict[str, Any]) -> Tensor:
        return self.denoise(context, x_t, torch.stack([t, s], dim=1))

    def use_sampling_mode(self, mode: SamplingMode | Callable[[], SamplingMode]) -> None:
        """Make LeRobot's own ``predict_action_chunk`` / ``select_action`` sample with ``mode``: SnapFlow
        1-NFE for deployment, or ``teacher-N`` to run the same checkpoint as the N-step teacher. A callable is
        asked at every chunk (a student reads its config then, and refuses a jump it was never distilled for).
        With RTC enabled in the policy's config, the previous chunk LeRobot passes is continued
        (:mod:`snapflow.adapters.lerobot.rtc`: LeRobot's guided RTC per Euler step, prefix inpainting for jumps)."""
        adapter = self
        current = mode if callable(mode) else lambda: mode

        def sample_actions(
            model: nn.Module,
            *inputs: Any,
            noise: Tensor | None = None,
            inference_delay: int | None = None,
            prev_chunk_left_over: Tensor | None = None,
            execution_horizon: int | None = None,
            **_: Any,
        ) -> Tensor:
            chosen = current()
            processor = rtc_processor_in_force(model)
            context = adapter.encode_inputs(*inputs)
            if noise is None:
                masks = context["prefix_pad_masks"]
                noise = model.sample_noise(
                    (masks.shape[0], model.config.chunk_size, model.config.max_action_dim), masks.device
                )
            velocity = lambda x, t, s: adapter.velocity(x, t, s, context)  # noqa: E731
            return sample_with_rtc(
                velocity, noise, chosen, processor, prev_chunk_left_over, inference_delay, execution_horizon
            )

        self.policy.model.sample_actions = types.MethodType(sample_actions, self.policy.model)
        self.policy.reset()


__all__ = [
    "PROMPT_BUCKET",
    "OBS_LANGUAGE_ATTENTION_MASK",
    "OBS_LANGUAGE_TOKENS",
    "LeRobotFlowPolicy",
    "cache_for_one_pass",
    "cache_tensors",
    "modeling_module",
    "split_timestep",
]
