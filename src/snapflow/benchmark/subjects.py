"""What ``snapflow bench`` times: a policy under the FlowPolicy protocol with one batch-1 observation and noise.

Either a trained policy (a built-in checkpoint, a distilled LeRobot folder, or any LeRobot hub id or folder of a
declared type) or an architecture built at its real size with random weights: timing does not depend on the values,
so a user can time pi0.5 or GR00T N1.7 before downloading or training anything.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import torch
from torch import Tensor, nn

from snapflow.adapters.hub import check_source
from snapflow.adapters.lerobot_types import lerobot_policy_type
from snapflow.benchmark.architectures import architectures
from snapflow.errors import InvalidInputError
from snapflow.flow.modes import NAIVE_1, SNAPFLOW_1, SamplingMode
from snapflow.flow.time_sampling import TimeSampler
from snapflow.nn.snapflow_policy import SnapFlowPolicy
from snapflow.policies.checkpoint import BUILTIN_TIME_SAMPLER, LoadedPolicy, policy_metadata
from snapflow.policies.factory import POLICIES, default_config, make_model, make_processor, policy_type
from snapflow.policies.loaded import OpenedPolicy
from snapflow.policies.normalization import NormalizationStats
from snapflow.protocol import map_tensors
from snapflow.reporting.files import recorded_path

# the paper's LIBERO setting for the LeRobot architectures: two 224-pixel cameras, an 8-D state, 7-D actions
LIBERO_CAMERAS = ("observation.images.image", "observation.images.image2")
LIBERO_STATE_DIM, LIBERO_ACTION_DIM = 8, 7


@dataclass
class BenchSubject:
    """A policy with its batch-1 inputs; ``one_step`` is its 1-NFE mode: SnapFlow's jump, or the naive step for a
    teacher checkpoint (no target-time embedding)."""

    name: str
    policy: nn.Module
    observation: Any
    noise: Tensor
    details: dict[str, Any] = field(default_factory=dict)
    one_step: SamplingMode = SNAPFLOW_1
    #: the only modes the policy runs (an ONNX export runs its one jump), or None for any
    only_modes: tuple[SamplingMode, ...] | None = None
    #: the flow-matching times it trains on (the cost of a distillation step draws them)
    time_sampler: TimeSampler = BUILTIN_TIME_SAMPLER
    #: the dtype it was asked to run in (what runs, as timed, is in the report's ``dtype``: a policy may keep layers
    #: in float32, and a fast path may change them)
    dtype: torch.dtype = torch.float32
    #: the number of steps its own sampler takes (a LeRobot policy's, as configured), timed beside the teacher modes
    own_steps: int | None = None


def _parameter_count(module: nn.Module) -> int:
    return sum(parameter.numel() for parameter in module.parameters())


def builtin_subject(
    loaded: LoadedPolicy, name: str, device: torch.device | str = "cpu", dtype: torch.dtype = torch.float32
) -> BenchSubject:
    """A built-in policy with a batch-1 observation made by its own processor (a zero state, the first instruction it
    knows, a black image where it reads one) and fixed noise: the values do not change the timing."""
    processor = loaded.processor
    torch.manual_seed(0)
    observation = _cast(processor.example_observation(), device, dtype)
    noise = torch.randn(1, processor.chunk_length, processor.action_dim).to(device=device, dtype=dtype)
    policy = loaded.policy.to(device=device, dtype=dtype).eval()
    return BenchSubject(
        name,
        policy,
        observation,
        noise,
        {
            "parameters": _parameter_count(policy),
            "policy_type": loaded.policy_type,
            "config": processor.config.to_dict(),
            **({loaded.export["format"]: loaded.export} if loaded.exported else {}),
        },
        # without phi_s (a teacher checkpoint) the one step is the naive one, timed and named as such
        SNAPFLOW_1 if loaded.exported or loaded.policy.target_time_embedding is not None else NAIVE_1,
        (SNAPFLOW_1,) if loaded.exported else None,
        loaded.time_sampler,
        dtype,
    )


def random_builtin_policy(name: str) -> LoadedPolicy:
    """Built-in policy ``name`` at its default size on Meta-World MT10's dimensions, with random weights and unit
    normalisation: what ``--architecture minivla`` times."""
    from snapflow.envs.metaworld import ACTION_DIM, MT10_INSTRUCTIONS, STATE_DIM

    instructions = list(MT10_INSTRUCTIONS.values())
    config = default_config(name, STATE_DIM, ACTION_DIM, instructions)
    state_dim = policy_type(name).processor_class.state_entries(config, instructions)
    processor = make_processor(
        config,
        NormalizationStats([0.0] * state_dim, [1.0] * state_dim, [0.0] * ACTION_DIM, [1.0] * ACTION_DIM),
        instructions,
    )
    policy = SnapFlowPolicy(make_model(config))
    return LoadedPolicy(policy, processor, policy_metadata(policy, processor), Path(f"<random {name}>"))


def _cast(observation: Any, device: torch.device, dtype: torch.dtype) -> Any:
    """Floating-point tensors of an observation to ``dtype`` and every tensor to ``device``."""
    return map_tensors(
        observation,
        lambda tensor: tensor.to(device=device, dtype=dtype if tensor.is_floating_point() else tensor.dtype),
    )


def exported_lerobot_subject(loaded: Any, name: str) -> BenchSubject:
    """An export of a distilled LeRobot policy (``LoadedLeRobotPolicy``), timed at the one jump it runs."""
    from snapflow.adapters.lerobot.evaluation import lerobot_observation
    from snapflow.adapters.lerobot.registry import lerobot_chunk_shape

    config = loaded.config
    noise = torch.randn(1, *lerobot_chunk_shape(config))
    observation = lerobot_observation(config, torch.device("cpu"))
    details = {"policy_type": config.type, loaded.export["format"]: loaded.export}
    return BenchSubject(
        name, loaded.policy, observation, noise, details, SNAPFLOW_1, (SNAPFLOW_1,), loaded.time_sampler
    )


def lerobot_subject(
    policy: nn.Module, name: str, device: torch.device, dtype: torch.dtype, one_step: SamplingMode = SNAPFLOW_1
) -> BenchSubject:
    """Any LeRobot policy of a declared type under its SnapFlow adapter (phi_s included, as the student runs), its 1-NFE
    mode ``one_step``."""
    from snapflow.adapters.lerobot import LeRobotFlowPolicy, wrap_policy
    from snapflow.adapters.lerobot.registry import lerobot_time_sampler

    adapter = policy if isinstance(policy, LeRobotFlowPolicy) else wrap_policy(policy)
    inner = adapter.policy
    inner.config.device = str(device)
    adapter.to(device)
    if dtype != torch.float32:
        adapter.run_in(dtype)
    adapter.eval()
    config = inner.config
    noise = torch.randn(1, *adapter.action_shape, device=device)
    expert = _parameter_count(nn.ModuleList(adapter.expert_modules()))
    return BenchSubject(
        name,
        adapter,
        adapter.example_observation(device),
        noise,
        {
            "parameters": _parameter_count(adapter),
            "expert_parameters": expert,
            "policy_type": adapter.policy_type,
            "chunk_size": adapter.action_shape[0],
            "tokens": getattr(config, "tokenizer_max_length", None),  # GR00T's prompt has no fixed length
            "cameras": list(config.image_features),
        },
        one_step=one_step,
        time_sampler=lerobot_time_sampler(config),
        dtype=dtype,
        own_steps=type(adapter).own_steps(config),
    )


def lerobot_architecture(policy_type: str, device: torch.device, vlm: str | None = None) -> nn.Module:
    """LeRobot's policy of the declared type ``policy_type`` at full size with random weights, in the paper's LIBERO
    setting (two 224-pixel cameras, 8-D state, 7-D actions).

    A type that reads a VLM's config and processor (its declaration's ``vlm_options``) reads them from ``vlm``
    (default: LeRobot's, a hub id); no weights are downloaded.
    """
    from huggingface_hub.constants import CONFIG_NAME
    from lerobot.configs.types import FeatureType, PolicyFeature
    from lerobot.policies.factory import get_policy_class, make_policy_config

    from snapflow.adapters.lerobot.registry import adapter_class

    adapter_class(policy_type)  # names an unsupported type or too old a LeRobot before a long build
    declared = lerobot_policy_type(policy_type)
    features = {
        "input_features": {
            "observation.state": PolicyFeature(type=FeatureType.STATE, shape=(LIBERO_STATE_DIM,)),
            **{camera: PolicyFeature(type=FeatureType.VISUAL, shape=(3, 224, 224)) for camera in LIBERO_CAMERAS},
        },
        "output_features": {"action": PolicyFeature(type=FeatureType.ACTION, shape=(LIBERO_ACTION_DIM,))},
    }
    extra = {**declared.architecture_options, **{option: vlm for option in declared.vlm_options if vlm}}
    config = make_policy_config(policy_type, device=str(device), push_to_hub=False, **features, **extra)
    for option in declared.vlm_options:  # named in one line before the build reads the VLM's config and processor
        check_source(getattr(config, option), CONFIG_NAME, f"a VLM for {declared.class_stem}")
    with torch.device(device):  # built where it runs: a full-size pi0.5 takes minutes on the CPU, seconds on a GPU
        return get_policy_class(policy_type)(config)


def parameter_totals(module: nn.Module) -> dict[str, int]:
    """Parameter count per dtype over all of ``module``."""
    totals: dict[str, int] = {}
    for parameter in module.parameters():
        name = str(parameter.dtype).removeprefix("torch.")
        totals[name] = totals.get(name, 0) + parameter.numel()
    return totals


def parameter_dtypes(module: nn.Module, depth: int = 3) -> dict[str, dict[str, int]]:
    """Parameter count per dtype of each module group (the module's children down to ``depth`` levels, where a
    group's parameters are not all of one dtype, its children are listed instead): what actually runs in which
    precision, which a single dtype would hide (LeRobot keeps some layers in float32 under bfloat16). A module whose
    only content is one child (an adapter around its policy) is walked through without spending a level."""
    groups: dict[str, dict[str, int]] = {}

    def visit(prefix: str, child: nn.Module, level: int) -> None:
        counts = parameter_totals(child)
        if not counts:
            return
        children = list(child.named_children())
        if len(counts) > 1 and level < depth and children:
            wrapper = len(children) == 1 and not any(True for _ in child.parameters(recurse=False))
            for name, grandchild in children:
                visit(f"{prefix}.{name}" if prefix else name, grandchild, level + (not wrapper))
            own = {str(p.dtype).removeprefix("torch."): 0 for p in child.parameters(recurse=False)}
            for parameter in child.parameters(recurse=False):
                own[str(parameter.dtype).removeprefix("torch.")] += parameter.numel()
            if own:
                groups[f"{prefix} (own)"] = own
            return
        groups[prefix or "(all)"] = counts

    visit("", module, 0)
    return groups


def make_subject(
    policy: str | None, architecture: str | None, device: torch.device, dtype: torch.dtype, vlm: str | None = None
) -> BenchSubject:
    """The subject the CLI names: ``--policy`` (a built-in checkpoint, a distilled LeRobot folder, or a LeRobot hub id
    or folder) or ``--architecture`` (random weights at full size; ``minivla`` is the demo's policy)."""
    if (policy is None) == (architecture is None):
        raise InvalidInputError("give either --policy or --architecture")
    if architecture is not None:
        if architecture not in architectures():
            raise InvalidInputError(
                f"unknown architecture {architecture!r}; choose one of {', '.join(architectures())}"
            )
        if architecture in POLICIES:
            return builtin_subject(
                random_builtin_policy(architecture), f"{architecture} (random weights)", device, dtype
            )
        return lerobot_subject(
            lerobot_architecture(architecture, device, vlm),
            f"{architecture} (full size, random weights)",
            device,
            dtype,
        )
    from snapflow.sources import open_policy

    loaded = open_policy(policy)
    return opened_subject(loaded, f"{loaded.policy_type} ({recorded_path(policy)})", device, dtype)


def with_prompt_tokens(subject: BenchSubject, tokens: int) -> BenchSubject:
    """``subject`` timed on a prompt of ``tokens`` real tokens, the rest of its padded length padding (a LeRobot
    subject's prompt is all real tokens by default: the most a prefix can cost); recorded as
    ``details["prompt_tokens"]``."""
    from snapflow.adapters.lerobot.base import OBS_LANGUAGE_ATTENTION_MASK

    observation = subject.observation
    if not isinstance(observation, dict) or OBS_LANGUAGE_ATTENTION_MASK not in observation:
        raise InvalidInputError(f"--prompt-tokens: {subject.name} reads no tokenized prompt (a LeRobot policy does)")
    mask = observation[OBS_LANGUAGE_ATTENTION_MASK]
    if not 1 <= tokens <= mask.shape[1]:
        raise InvalidInputError(f"--prompt-tokens must be in [1, {mask.shape[1]}] (the padded prompt), got {tokens}")
    real = torch.arange(mask.shape[1], device=mask.device)[None, :] < tokens
    observation = {**observation, OBS_LANGUAGE_ATTENTION_MASK: real.expand_as(mask).to(mask.dtype)}
    return replace(subject, observation=observation, details={**subject.details, "prompt_tokens": tokens})


def opened_subject(
    loaded: OpenedPolicy, name: str, device: torch.device | str = "cpu", dtype: torch.dtype = torch.float32
) -> BenchSubject:
    """The subject of an opened policy, by what it is: a built-in checkpoint (or its export), a LeRobot policy's
    export, or a LeRobot policy under its adapter."""
    if isinstance(loaded, LoadedPolicy):
        return builtin_subject(loaded, name, device, dtype)
    if loaded.exported:
        return exported_lerobot_subject(loaded, name)
    # never distilled (a teacher, or a student type whose config says so): its one step is the naive one, named so
    one_step = SNAPFLOW_1 if loaded.distilled else NAIVE_1
    return lerobot_subject(loaded.policy, name, torch.device(device), dtype, one_step)


__all__ = [
    "exported_lerobot_subject",
    "parameter_dtypes",
    "parameter_totals",
    "BenchSubject",
    "builtin_subject",
    "random_builtin_policy",
    "lerobot_subject",
    "lerobot_architecture",
    "make_subject",
    "opened_subject",
    "with_prompt_tokens",
]
