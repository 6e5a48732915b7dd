"""What ``snapflow bench`` times: a policy under the FlowPolicy protocol with one batch-1 observation and noise.

Either a trained policy (a built-in checkpoint, a distilled LeRobot folder, or any LeRobot pi0 / pi0.5 /
SmolVLA hub id or folder) or an architecture built at its real size with random weights: timing does not
depend on the values, so a user can time pi0.5 or SmolVLA before downloading or training anything.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch
from torch import Tensor, nn

ARCHITECTURES = ("minivla", "pi0", "pi05", "smolvla")
# the paper's LIBERO setting for the LeRobot architectures: two 224-pixel cameras, an 8-D state, 7-D actions
LIBERO_CAMERAS = ("observation.images.image", "observation.images.image2")
LIBERO_STATE_DIM, LIBERO_ACTION_DIM = 8, 7


@dataclass
class BenchSubject:
    name: str
    policy: nn.Module
    observation: Any
    noise: Tensor
    details: dict[str, Any] = field(default_factory=dict)


def _parameter_count(module: nn.Module) -> int:
    return sum(parameter.numel() for parameter in module.parameters())


def builtin_subject(path: str | None, device: torch.device, dtype: torch.dtype) -> BenchSubject:
    """A built-in MiniVLA checkpoint, or (``path=None``) the demo's architecture with random weights."""
    from snapflow.experiments.metaworld import PRESETS
    from snapflow.nn.snapflow_policy import SnapFlowPolicy
    from snapflow.policies.minivla import MiniVLA
    from snapflow.training.checkpoint import load_policy

    if path is None:
        config, policy, name = PRESETS["fast"].policy, SnapFlowPolicy(MiniVLA(PRESETS["fast"].policy)), "minivla (random weights)"
    else:
        loaded = load_policy(path)
        config, policy, name = loaded.processor.config, loaded.policy, f"minivla ({path})"
    observation: dict[str, Tensor] = {
        "state": torch.randn(1, config.state_dim, device=device, dtype=dtype),
        "tokens": torch.ones(1, config.max_instruction_tokens, dtype=torch.long, device=device),
        "token_mask": torch.ones(1, config.max_instruction_tokens, dtype=torch.bool, device=device),
    }
    if config.use_image:
        observation["image"] = torch.rand(1, 3, config.image_size, config.image_size, device=device, dtype=dtype)
    policy = policy.to(device=device, dtype=dtype).eval()
    noise = torch.randn(1, config.chunk_length, config.action_dim, device=device, dtype=dtype)
    return BenchSubject(name, policy, observation, noise, {"parameters": _parameter_count(policy), "config": config.to_dict()})


def lerobot_observation(policy: nn.Module, device: torch.device) -> dict[str, Tensor]:
    """A batch-1 observation as LeRobot's pre-processor hands it to the model: images in [0, 1], normalised
    state, a full-length token sequence (the values do not change the timing)."""
    config = policy.config
    observation = {key: torch.rand(1, *feature.shape, device=device) for key, feature in config.image_features.items()}
    if config.robot_state_feature is not None:
        observation["observation.state"] = torch.randn(1, *config.robot_state_feature.shape, device=device)
    length = config.tokenizer_max_length
    observation["observation.language.tokens"] = torch.zeros(1, length, dtype=torch.long, device=device)  # id 0: in every vocabulary
    observation["observation.language.attention_mask"] = torch.ones(1, length, dtype=torch.bool, device=device)
    return observation


def lerobot_subject(policy: nn.Module, name: str, device: torch.device, dtype: torch.dtype) -> BenchSubject:
    """Any LeRobot pi0 / pi0.5 / SmolVLA under its SnapFlow adapter (phi_s included, as the student runs)."""
    from snapflow.adapters.lerobot import LeRobotFlowPolicy, wrap_policy

    adapter = policy if isinstance(policy, LeRobotFlowPolicy) else wrap_policy(policy)
    inner = adapter.policy
    inner.config.device = str(device)
    adapter.to(device)
    if dtype != torch.float32:
        if adapter.policy_type == "smolvla" or dtype != torch.bfloat16:
            raise ValueError(f"LeRobot runs {adapter.policy_type} in {dtype} only through autocast; time it in float32, or pi0 / pi0.5 in bfloat16")
        # LeRobot's own mixed precision: the VLM and expert in bfloat16, the layers it keeps in float32 kept
        inner.model.paligemma_with_expert.to_bfloat16_for_selected_params("bfloat16")
    adapter.eval()
    config = inner.config
    noise = torch.randn(1, config.chunk_size, config.max_action_dim, device=device)
    expert = _parameter_count(nn.ModuleList(adapter.expert_modules()))
    return BenchSubject(name, adapter, lerobot_observation(inner, device), noise,
                        {"parameters": _parameter_count(adapter), "expert_parameters": expert, "policy_type": adapter.policy_type,
                         "chunk_size": config.chunk_size, "tokens": config.tokenizer_max_length,
                         "cameras": list(config.image_features)})


def lerobot_architecture(policy_type: str, device: torch.device, vlm: str | None = None) -> nn.Module:
    """LeRobot's pi0, pi0.5 or SmolVLA at full size with random weights, in the paper's LIBERO setting.

    SmolVLA reads its VLM's config and processor from ``vlm`` (default: LeRobot's, a hub id); with
    ``load_vlm_weights=False`` no weights are downloaded.
    """
    from lerobot.configs.types import FeatureType, PolicyFeature
    from lerobot.policies.factory import get_policy_class, make_policy_config

    from snapflow.adapters.lerobot.registry import adapter_class

    adapter_class(policy_type)  # names an unsupported type or too old a LeRobot before a long build
    features = {
        "input_features": {
            "observation.state": PolicyFeature(type=FeatureType.STATE, shape=(LIBERO_STATE_DIM,)),
            **{camera: PolicyFeature(type=FeatureType.VISUAL, shape=(3, 224, 224)) for camera in LIBERO_CAMERAS},
        },
        "output_features": {"action": PolicyFeature(type=FeatureType.ACTION, shape=(LIBERO_ACTION_DIM,))},
    }
    extra: dict[str, Any] = {"load_vlm_weights": False, **({"vlm_model_name": vlm} if vlm else {})} if policy_type == "smolvla" else {}
    config = make_policy_config(policy_type, device=str(device), push_to_hub=False, **features, **extra)
    return get_policy_class(policy_type)(config)


def make_subject(policy: str | None, architecture: str | None, device: torch.device, dtype: torch.dtype, vlm: str | None = None) -> BenchSubject:
    """The subject the CLI names: ``--policy`` (a checkpoint, a distilled LeRobot folder, or a LeRobot hub id
    or folder) or ``--architecture`` (random weights at full size; ``minivla`` is the demo's policy)."""
    if (policy is None) == (architecture is None):
        raise ValueError("give either --policy or --architecture")
    if architecture is not None:
        if architecture not in ARCHITECTURES:
            raise ValueError(f"unknown architecture {architecture!r}; choose one of {', '.join(ARCHITECTURES)}")
        if architecture == "minivla":
            return builtin_subject(None, device, dtype)
        return lerobot_subject(lerobot_architecture(architecture, device, vlm), f"{architecture} (full size, random weights)", device, dtype)
    from snapflow.training.checkpoint import LATEST, POLICY_CONFIG

    local = Path(policy)
    if (local / POLICY_CONFIG).is_file() or (local / LATEST).is_file():  # what resolve_checkpoint accepts
        return builtin_subject(policy, device, dtype)
    from snapflow.adapters.lerobot import load_distilled, load_pretrained_policy
    from snapflow.adapters.lerobot.checkpoint import SNAPFLOW_MARKER

    loaded = load_distilled(local) if (local / SNAPFLOW_MARKER).is_file() else load_pretrained_policy(policy)
    return lerobot_subject(loaded, policy, device, dtype)


__all__ = ["ARCHITECTURES", "BenchSubject", "builtin_subject", "lerobot_observation", "lerobot_subject", "lerobot_architecture", "make_subject"]
