"""What every LeRobot flow-matching policy shares under SnapFlow, naming no one policy's fields.

A type's adapter says three things: where its time embedding enters (it replaces that method on the model
*instance*, LeRobot's files untouched, by one that reads a timestep of shape (B, 2) as [t, s] and adds phi_s(s)
there; a plain (B,) timestep means s = t, so LeRobot's own ``forward`` and sampler keep running the flow-matching
teacher), its prefix pass (the observation through the frozen VLM once) and one velocity from that prefix. The base
holds the rest: phi_s stored inside LeRobot's model, the frozen prefix pass, the prompt's padding, the training times,
noise, and LeRobot's own action API sampling any mode. s travels as an argument, never as hook state, so gradient
checkpointing recomputes the same values. The pi0 family's key/value-cache layout is :mod:`.prefix_cache`.
"""

from __future__ import annotations

import contextlib
import sys
import types
from abc import ABC, abstractmethod
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any, ClassVar

import torch
from torch import Tensor, nn

from snapflow.adapters.lerobot.rtc import TrainedPrefix, rtc_processor_in_force, sample_with_rtc, trained_max_delay
from snapflow.adapters.lerobot_config import SmolVLMSize
from snapflow.errors import InvalidInputError
from snapflow.flow.modes import SamplingMode
from snapflow.flow.time_sampling import BetaTimeSampler, TimeSampler
from snapflow.nn.time_embedding import TargetTimeEmbedding
from snapflow.protocol import map_tensors

#: LeRobot's batch keys
OBS_STATE, ACTION = "observation.state", "action"
OBS_LANGUAGE_TOKENS = "observation.language.tokens"
OBS_LANGUAGE_ATTENTION_MASK = "observation.language.attention_mask"
#: a prompt cut of its padding keeps a multiple of this many tokens: a compiled prefix then meets few shapes
PROMPT_BUCKET = 16

#: ``sample(inputs, noise, inference_delay, prev_chunk_left_over, execution_horizon, context=None) -> chunk``: what
#: :meth:`LeRobotFlowPolicy.use_sampling_mode` hands a type's :meth:`~LeRobotFlowPolicy.install_sampler`; ``context``
#: instead of ``inputs`` where the policy's own sampling receives its prefix encoded already
ChunkSampler = Callable[..., Tensor]


def split_timestep(timestep: Tensor) -> tuple[Tensor, Tensor]:
    """(B,) -> (t, t), LeRobot's own calls; (B, 2) -> (t, s), the adapter's calls."""
    return (timestep, timestep) if timestep.ndim == 1 else timestep.unbind(dim=1)


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


class LeRobotFlowPolicy(nn.Module, ABC):
    """A LeRobot policy seen through :class:`snapflow.protocol.FlowPolicy`.

    Batches are what the policy's own pre-processor produces (normalised state, images in [0, 1], language
    tokens and mask). Actions are (B, *:attr:`action_shape`), padded as the policy pads its training targets.
    Subclasses name where time enters, the policy's prefix pass and one velocity, and how LeRobot samples.
    """

    policy_type: ClassVar[str]
    #: the config field that sets how many denoising steps its own sampler takes a chunk (each type names it its way)
    steps_field: ClassVar[str]
    #: the oldest LeRobot release whose internals the adapter follows
    minimum_lerobot: ClassVar[str] = "0.4.4"
    #: what :func:`snapflow.inference.compile_policy` compiles: the prefix pass LeRobot's sampling calls (``encode``
    #: goes through it too) and the velocity
    compiled_methods: ClassVar[tuple[str, str]] = ("encode_inputs", "velocity")
    #: whether the prompt's padding is masked out of every attention, so that cutting it changes no chunk
    masks_prompt_padding: ClassVar[bool] = True
    #: why the one-step graph (prefix and jump) cannot be exported (``snapflow export``), where it cannot
    export_refusal: ClassVar[str | None] = None

    def __init__(self, policy: nn.Module) -> None:
        super().__init__()
        self.policy = policy
        #: the prefix pass keeps its graph (a teacher trained from scratch); distillation keeps the VLM frozen
        self.train_prefix = False
        model = self.time_owner
        if not hasattr(model, "target_time_embedding"):
            embedding = self.new_target_time_embedding()
            device = next(model.parameters()).device
            model.target_time_embedding = embedding.to(device)
            self.install_target_time(model)

    @property
    def time_owner(self) -> nn.Module:
        """The module of the policy that holds phi_s (``target_time_embedding``) and whose method reads the time:
        LeRobot's ``policy.model`` where it has one."""
        return self.policy.model

    @property
    def target_time_embedding(self) -> TargetTimeEmbedding:
        """phi_s, stored inside the LeRobot model so that LeRobot's own checkpoints carry it (registered once:
        safetensors refuses tensors saved under two names)."""
        return self.time_owner.target_time_embedding

    @abstractmethod
    def new_target_time_embedding(self) -> TargetTimeEmbedding:
        """phi_s at zero, as wide as the layer it is added to, over the sinusoid periods of the policy's own time."""

    @abstractmethod
    def install_target_time(self, model: nn.Module) -> None:
        """Replace, on ``model`` (:attr:`time_owner`), the method where the policy's time enters by one that reads a
        (B, 2) timestep as [t, s] and adds ``model.target_time_embedding(s)`` there."""

    @abstractmethod
    def expert_modules(self) -> list[nn.Module]:
        """The action expert and its projections: what distillation trains besides phi_s."""

    def expert_parameters(self) -> list[nn.Parameter]:
        """What distillation trains, as in the paper: the action expert, its projections and phi_s; the VLM
        stays frozen. Each once, where phi_s lives inside the expert (an optimizer would step a repeated one twice)."""
        modules = [*self.expert_modules(), self.target_time_embedding]
        return list({id(parameter): parameter for module in modules for parameter in module.parameters()}.values())

    @classmethod
    def scratch_config(
        cls, vlm: Path, input_features: dict[str, Any], output_features: dict[str, Any], size: SmolVLMSize, **sizes: Any
    ) -> Any:
        """The LeRobot config of a policy of this type trained from scratch (``snapflow train --policy-type``, a
        sweep's ``lerobot`` run): random weights over the SmolVLM folder ``vlm`` written locally (its config, its
        word-level tokenizer of the dataset's instructions), its VLM's towers at ``size``'s widths and depths;
        ``sizes`` are the chunk's (``chunk_size``, ``n_action_steps``, ``tokenizer_max_length``). Only the types
        declared ``trains_from_scratch`` build one."""
        raise InvalidInputError(f"snapflow does not train LeRobot's {cls.policy_type} from scratch")

    @classmethod
    def chunk_shape(cls, config: Any) -> tuple[int, int]:
        """(chunk length, action width) of the noise and of the chunk a policy of ``config`` samples, padding
        included: LeRobot's ``chunk_size`` and ``max_action_dim`` where it has them."""
        return config.chunk_size, config.max_action_dim

    @classmethod
    def own_steps(cls, config: Any) -> int:
        """How many denoising steps the policy of ``config`` takes a chunk by its own sampler, as configured
        (:attr:`steps_field`)."""
        return getattr(config, cls.steps_field)

    @property
    def action_shape(self) -> tuple[int, int]:
        """:meth:`chunk_shape` of this policy's config."""
        return self.chunk_shape(self.policy.config)

    def action_targets(self, batch: dict[str, Tensor]) -> Tensor:
        """The batch's action chunk as the policy's training forward pads it."""
        return self.policy.prepare_action(batch)

    def loss_cuts_padded_width(self) -> bool:
        """Whether the policy's own loss leaves out the chunk's padded action width (pi0's and pi0.5's training
        forward cuts its losses to the dataset's action width)."""
        return True

    def action_weights(self, batch: dict[str, Tensor]) -> Tensor | None:
        """1 on the dataset's action width and 0 on the padding past it, where the policy's own loss cuts that
        padding off (:meth:`loss_cuts_padded_width`), so the objective weighs what the teacher was trained on
        (:class:`snapflow.protocol.PaddedActions`); None where the chunk is no wider than the actions (a policy
        trained from scratch here pads to its own width) or the policy's loss weighs its padding too."""
        width = self.action_shape[1]
        actions = self.policy.config.action_feature.shape[0]
        if actions >= width or not self.loss_cuts_padded_width():
            return None
        device = next(self.policy.parameters()).device
        return torch.arange(width, device=device) < actions

    @classmethod
    def env_processors(cls, env_config: Any, config: Any) -> tuple[Any, Any]:
        """The (pre, post) processors between LeRobot's environment of ``env_config`` and a policy of ``config`` in
        LeRobot's rollout: LeRobot's own choice."""
        from lerobot.envs.factory import make_env_pre_post_processors

        return make_env_pre_post_processors(env_config, config)

    @classmethod
    def training_time_sampler(cls, config: Any) -> TimeSampler:
        """The flow-matching times a policy of ``config`` trains on, read from its config where LeRobot keeps
        them (pi0 / pi0.5: ``time_sampling_beta_alpha`` / ``_beta``); SmolVLA's code fixes Beta(1.5, 1). Every one
        shifts them into [0.001, 1]."""
        alpha = getattr(config, "time_sampling_beta_alpha", 1.5)
        beta = getattr(config, "time_sampling_beta_beta", 1.0)
        if beta != 1.0:
            raise InvalidInputError(
                f"this {config.type} samples times from Beta({alpha}, {beta}); snapflow samples Beta(a, 1) only"
            )
        return BetaTimeSampler(concentration=alpha, min_time=0.001)

    def run_in(self, dtype: torch.dtype) -> None:
        """Run the policy in ``dtype`` as LeRobot itself does, or refuse where LeRobot has no such precision (a
        policy run in another dtype only through autocast)."""
        raise InvalidInputError(f"LeRobot runs {self.policy_type} in {dtype} only through autocast; time it in float32")

    def prefix_pass(self, vlm: nn.Module) -> contextlib.AbstractContextManager:
        """How the prefix runs: :func:`frozen_prefix_pass` unless ``train_prefix``, then as it is, with gradients;
        as it is too where it is frozen already (no gradients, the VLM in eval mode: deployment), which keeps a
        compiled prefix in one graph (torch.compile breaks its graph at a generator's context manager)."""
        if self.train_prefix or (not torch.is_grad_enabled() and not vlm.training):
            return contextlib.nullcontext()
        return frozen_prefix_pass(vlm)

    @abstractmethod
    def model_inputs(self, batch: dict[str, Tensor]) -> tuple[Any, ...]:
        """The positional inputs the policy's own sampling hands its model (what :meth:`install_sampler`'s
        replacement receives)."""

    @abstractmethod
    def encode_inputs(self, *inputs: Any) -> dict[str, Any]:
        """Prefix pass from :meth:`model_inputs`: images, instruction (and state) through the frozen VLM once,
        without gradients, keeping what each velocity reads (a key/value cache, features) as tensors."""

    @abstractmethod
    def denoise(self, context: dict[str, Any], x_t: Tensor, timestep: Tensor) -> Tensor:
        """The policy's velocity at ``x_t`` from the context's prefix; ``timestep`` (B,) or (B, 2) as [t, s]."""

    def encode(self, batch: dict[str, Tensor]) -> dict[str, Any]:
        return self.encode_inputs(*self.model_inputs(batch))

    def without_prompt_padding(self, batch: dict[str, Tensor], multiple: int = PROMPT_BUCKET) -> dict[str, Tensor]:
        """``batch`` with its prompt's right padding cut down to its longest prompt, rounded up to ``multiple``
        tokens. Padding is masked out of every attention and position ids count real tokens only, so the chunk is
        the same for fewer tokens through the VLM (LeRobot's pi0.5 pads every prompt to 200 tokens). A batch whose
        padding is not on the right, or a policy that attends to its padding (:attr:`masks_prompt_padding`), is
        returned as it is."""
        if not self.masks_prompt_padding:
            return batch
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

    def draw_noise(self, context: dict[str, Any], batch_size: int) -> Tensor:
        """The noise a chunk starts from where LeRobot's caller gives none: a standard normal of
        (``batch_size``, *:attr:`action_shape`) on the context's device, from torch's global generator."""
        device = _first_tensor(context).device
        return torch.randn((batch_size, *self.action_shape), device=device)

    def example_observation(self, device: torch.device) -> dict[str, Tensor]:
        """A batch-1 observation as the policy's pre-processor hands it to the model, for timing and tracing (which
        its values do not change): :func:`lerobot_observation` of its config, unless the policy's batch looks
        otherwise."""
        return lerobot_observation(self.policy.config, device)

    def lone_chunk_batch(self, batch: dict[str, Tensor]) -> dict[str, Tensor]:
        """The batch a ``predict_action_chunk`` called on its own hands the policy (LeRobot's policy server calls it
        once an observation, with no ``select_action`` before it). The batch itself, unless the policy reads its
        observations from queues that only its ``select_action`` fills."""
        return batch

    @abstractmethod
    def install_sampler(self, sample: ChunkSampler) -> None:
        """Make the policy's own ``predict_action_chunk`` / ``select_action`` call ``sample`` with the inputs it
        hands its model (:meth:`model_inputs`) and whatever noise and RTC arguments it passes."""

    def use_sampling_mode(self, mode: SamplingMode | Callable[[], SamplingMode]) -> None:
        """Make LeRobot's own ``predict_action_chunk`` / ``select_action`` sample with ``mode``: SnapFlow
        1-NFE for deployment, or ``teacher-N`` to run the same checkpoint as the N-step teacher. A callable is
        asked at every chunk (a student reads its config then, and refuses a jump it was never distilled for).
        With RTC enabled in the policy's config, the previous chunk LeRobot passes is continued
        (:mod:`snapflow.adapters.lerobot.rtc`: LeRobot's guided RTC per Euler step, prefix inpainting for jumps, or,
        in its ``trained`` mode, the prefix given to every pass)."""
        current = mode if callable(mode) else lambda: mode

        def sample(
            inputs: tuple[Any, ...],
            noise: Tensor | None = None,
            inference_delay: int | None = None,
            prev_chunk_left_over: Tensor | None = None,
            execution_horizon: int | None = None,
            context: dict[str, Any] | None = None,
        ) -> Tensor:
            chosen = current()
            processor = rtc_processor_in_force(self.time_owner)
            if context is None:  # a policy whose sampling gets its prefix already encoded passes it instead
                context = self.encode_inputs(*inputs)
            if noise is None:
                noise = self.draw_noise(context, _first_tensor(context).shape[0])
            velocity = lambda x, t, s: self.velocity(x, t, s, context)  # noqa: E731
            trained = TrainedPrefix(self, context, trained_max_delay(self.time_owner))
            return sample_with_rtc(
                velocity, noise, chosen, processor, prev_chunk_left_over, inference_delay, execution_horizon, trained
            )

        self.install_sampler(sample)
        self.policy.reset()


def lerobot_observation(config: Any, device: torch.device) -> dict[str, Tensor]:
    """A batch-1 observation as LeRobot's pre-processor hands it to the model of ``config``: images in [0, 1],
    normalised state, a full-length token sequence (for timing and tracing, which the values do not change)."""
    # a policy that reads several observation steps (multi-task DiT) gets them, as its queues hold them
    count = getattr(config, "n_obs_steps", 1)
    steps = (count,) if count > 1 else ()
    observation = {
        key: torch.rand(1, *steps, *feature.shape, device=device) for key, feature in config.image_features.items()
    }
    if config.robot_state_feature is not None:
        observation[OBS_STATE] = torch.randn(1, *steps, *config.robot_state_feature.shape, device=device)
    length = config.tokenizer_max_length
    # id 0: in every vocabulary
    observation[OBS_LANGUAGE_TOKENS] = torch.zeros(1, length, dtype=torch.long, device=device)
    observation[OBS_LANGUAGE_ATTENTION_MASK] = torch.ones(1, length, dtype=torch.bool, device=device)
    return observation


def _first_tensor(context: dict[str, Any]) -> Tensor:
    """A context's first tensor (its batch size leads, it lies on the policy's device), found by the protocol's own
    walk over nested contexts."""
    found: list[Tensor] = []
    map_tensors(context, lambda tensor: found.append(tensor) or tensor)
    return found[0]


__all__ = [
    "PROMPT_BUCKET",
    "OBS_LANGUAGE_ATTENTION_MASK",
    "OBS_LANGUAGE_TOKENS",
    "ChunkSampler",
    "LeRobotFlowPolicy",
    "frozen_prefix_pass",
    "lerobot_observation",
    "modeling_module",
    "split_timestep",
]
