"""``torch.compile`` of a policy's one-pass velocity, the call every denoising step makes.

The compiled function replaces ``policy.velocity`` on the instance, so every sampler that calls it runs compiled:
:func:`snapflow.flow.sample_actions` (``snapflow eval``, ``snapflow bench``) and a LeRobot adapter's
``use_sampling_mode`` (LeRobot's own ``select_action`` / ``predict_action_chunk``). The prefix pass runs once per
chunk and stays eager.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Literal, get_args

if TYPE_CHECKING:
    from torch import nn

CompileMode = Literal["default", "reduce-overhead", "max-autotune"]
COMPILE_MODES: tuple[str, ...] = get_args(CompileMode)


def compile_policy(policy: nn.Module, mode: CompileMode = "default") -> nn.Module:
    """Compile ``policy.velocity`` in place (``reduce-overhead`` captures it in a CUDA graph on a GPU); returns ``policy``."""
    if mode not in COMPILE_MODES:
        raise ValueError(f"unknown compile mode {mode!r}; choose one of {', '.join(COMPILE_MODES)}")
    import torch  # here, not at import: the CLI lists the modes before torch loads

    policy.velocity = torch.compile(policy.velocity, mode=mode, dynamic=False)
    return policy


__all__ = ["CompileMode", "COMPILE_MODES", "compile_policy"]
