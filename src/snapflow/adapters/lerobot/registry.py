"""Which SnapFlow adapter serves which LeRobot policy, as :mod:`snapflow.adapters.lerobot_types` declares. It never
imports the plugin (the student types), which builds on it."""

from __future__ import annotations

from importlib.metadata import version
from typing import Any

from packaging.version import Version
from torch import nn

from snapflow._lazy import resolve
from snapflow.adapters.lerobot.base import LeRobotFlowPolicy
from snapflow.adapters.lerobot_types import LEROBOT_POLICY_TYPES, lerobot_policy_type
from snapflow.errors import InvalidInputError
from snapflow.flow.time_sampling import TimeSampler


def adapter_class(policy_type: str) -> type[LeRobotFlowPolicy]:
    """The adapter for a declared LeRobot policy type, checked against the installed LeRobot."""
    adapter: type[LeRobotFlowPolicy] = resolve(lerobot_policy_type(policy_type).adapter)
    installed = version("lerobot")
    if Version(installed) < Version(adapter.minimum_lerobot):
        raise InvalidInputError(
            f"snapflow's {policy_type} adapter needs lerobot >= {adapter.minimum_lerobot} (Python >= 3.12 for "
            f"lerobot >= 0.5); lerobot {installed} is installed"
        )
    return adapter


def base_policy_type(config: Any) -> str:
    """The LeRobot policy type whose adapter serves ``config``: a SnapFlow student's (``snapflow_smolvla``,
    :mod:`snapflow.adapters.lerobot.plugin`) is the type it was distilled from."""
    return getattr(config, "base_type", config.type)


def lerobot_time_sampler(config: Any) -> TimeSampler:
    """The flow-matching times a LeRobot policy (or a student) of ``config`` trains on, as its adapter reads them."""
    return adapter_class(base_policy_type(config)).training_time_sampler(config)


def lerobot_own_steps(config: Any) -> int:
    """How many denoising steps a LeRobot policy (or a student) of ``config`` takes a chunk by its own sampler, as
    its type's own field sets it."""
    return adapter_class(base_policy_type(config)).own_steps(config)


def lerobot_chunk_shape(config: Any) -> tuple[int, int]:
    """(chunk length, action width, padding included) a LeRobot policy (or a student) of ``config`` samples."""
    return adapter_class(base_policy_type(config)).chunk_shape(config)


def lerobot_env_processors(env_config: Any, config: Any) -> tuple[Any, Any]:
    """The (pre, post) processors between LeRobot's environment of ``env_config`` and a policy (or a student) of
    ``config``, as its adapter chooses them; LeRobot's own choice for a type snapflow does not declare."""
    policy_type = base_policy_type(config)
    if policy_type not in LEROBOT_POLICY_TYPES:
        return LeRobotFlowPolicy.env_processors(env_config, config)
    return adapter_class(policy_type).env_processors(env_config, config)


def wrap_policy(policy: nn.Module) -> LeRobotFlowPolicy:
    """The SnapFlow adapter for a LeRobot policy of a declared type (phi_s added at zero), or for a SnapFlow
    student of one (its phi_s kept).

    Args:
        policy: a LeRobot policy (``SmolVLAPolicy``, ``PI0Policy``, ...) of a type
            :mod:`snapflow.adapters.lerobot_types` declares, or a student of one.

    Returns:
        The policy as a :class:`~snapflow.protocol.FlowPolicy`; it holds ``policy``, edited in place (phi_s
        attached, its time embedding's method replaced on the instance), never copied.

    Raises:
        InvalidInputError: its type is not one snapflow declares, or the installed LeRobot is older than the
            type's adapter follows.

    Examples:
        Shown, not run: it needs LeRobot (``pip install "snapflow-vla[lerobot]"``) and the policy's weights from the
        hub. ``batch`` is one batch of the policy's dataset after LeRobot's own pre-processor.

        ```python
        from snapflow import SNAPFLOW_1, SnapFlowObjective
        from snapflow.adapters.lerobot import (
            load_pretrained_policy,
            save_distilled,
            wrap_policy,
        )

        teacher = load_pretrained_policy("lerobot/smolvla_base")
        student = wrap_policy(teacher)  # bit-identical to the teacher at init
        actions = student.action_targets(batch)
        loss = SnapFlowObjective()(student, batch, actions).loss
        loss.backward()  # an optimiser's step over student.expert_parameters()
        student.use_sampling_mode(SNAPFLOW_1)  # LeRobot's select_action: one jump
        save_distilled(student, "smolvla-student")  # lerobot-eval loads it
        ```
    """
    return adapter_class(base_policy_type(policy.config))(policy)


__all__ = [
    "adapter_class",
    "base_policy_type",
    "lerobot_chunk_shape",
    "lerobot_env_processors",
    "lerobot_time_sampler",
    "lerobot_own_steps",
    "wrap_policy",
]
