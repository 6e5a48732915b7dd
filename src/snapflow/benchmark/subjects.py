"""What ``snapflow bench`` times: a policy under the FlowPolicy protocol with one batch-1 observation and noise.

Either a trained policy (a built-in checkpoint, a distilled LeRobot folder, or any LeRobot hub id or folder of a
declared type) or an architecture built at its real size with random weights by its family: timing does not depend on
the values, so a user can time pi0.5 or GR00T N1.7 before downloading or training anything. Each opened policy makes
its own subject (:meth:`~snapflow.policies.loaded.OpenedPolicy.bench_subject`): nothing here asks what it is.
"""

from __future__ import annotations

from dataclasses import replace

import torch
from torch import nn

from snapflow.benchmark.architectures import architectures
from snapflow.errors import InvalidInputError
from snapflow.families import family_of
from snapflow.policies.loaded import BenchSubject
from snapflow.reporting.files import recorded_path


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
        loaded = family_of(architecture).random_policy(architecture, device, vlm)
        return loaded.bench_subject(f"{architecture} (full size, random weights)", device, dtype)
    from snapflow.sources import open_policy

    loaded = open_policy(policy)
    return loaded.bench_subject(f"{loaded.policy_type} ({recorded_path(policy)})", device, dtype)


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


__all__ = [
    "BenchSubject",
    "make_subject",
    "parameter_dtypes",
    "parameter_totals",
    "with_prompt_tokens",
]
