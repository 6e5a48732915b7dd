"""The deployment fast paths, by name: what ``snapflow bench --fast-path`` and ``snapflow eval --fast-path`` offer and
what :func:`apply_fast_path` runs. Plain Python: a fast path's function loads on first use, so the CLI lists the
names without importing torch.

A fast path is one :func:`register_fast_path` call: its name, a one-line description (the CLI's help lists it) and its
function as ``"module:name"``: a :class:`~snapflow.protocol.FlowPolicy` in, the same policy out, made faster in place
(as :func:`snapflow.inference.compile_policy` replaces ``encode`` and ``velocity`` on the instance). In place, because
every sampler then runs it: :func:`snapflow.flow.sample_actions` (``snapflow eval``, ``snapflow bench``) and a LeRobot
adapter's ``use_sampling_mode``, which LeRobot's own ``select_action`` / ``predict_action_chunk`` (``snapflow eval
--lerobot-env``) reach through the adapter instance.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from snapflow._lazy import resolve
from snapflow.errors import InvalidInputError
from snapflow.inference.deploy import DEPLOY_ACTION_BOUND  # plain Python: the module imports torch inside deploy()


@dataclass(frozen=True)
class FastPath:
    """One fast path: ``function`` (``"module:name"``) makes a policy faster in place; ``description`` says how;
    ``action_bound`` is the most it may move a one-step chunk's actions against the eager policy on the same inputs
    (None: float rounding only, as compiling reorders arithmetic)."""

    name: str
    function: str
    description: str
    action_bound: float | None = None

    def apply(self, policy: Any) -> Any:
        """Make ``policy`` faster in place; returns it."""
        function: Callable[[Any], Any] = resolve(self.function)
        if function(policy) is not policy:
            raise TypeError(
                f"fast path {self.name!r} returned another object: a fast path changes the policy it is given in "
                "place, so that every sampler holding it (LeRobot's among them) runs the fast path"
            )
        return policy


FAST_PATHS: dict[str, FastPath] = {}


def register_fast_path(name: str, function: str, description: str, action_bound: float | None = None) -> None:
    """Add fast path ``name`` (see the module's description)."""
    if name in FAST_PATHS:
        raise ValueError(f"a fast path named {name!r} is registered already")
    FAST_PATHS[name] = FastPath(name, function, description, action_bound)


def fast_path(name: str) -> FastPath:
    """The registered fast path ``name``, or a ValueError listing the known ones."""
    if name not in FAST_PATHS:
        raise InvalidInputError(f"unknown fast path {name!r}; choose one of {', '.join(FAST_PATHS)}")
    return FAST_PATHS[name]


def apply_fast_path(policy: Any, name: str) -> Any:
    """Make ``policy`` (a :class:`~snapflow.protocol.FlowPolicy`) faster in place with fast path ``name``; returns
    it."""
    return fast_path(name).apply(policy)


register_fast_path(
    "deploy",
    "snapflow.inference.deploy:deploy",
    "the recommended one for a distilled student on a GPU: pi0 / pi0.5's vision tower in bfloat16, TF32, "
    "compile-reduce-overhead, and the one-step chunk (prefix and jump) as one CUDA graph",
    action_bound=DEPLOY_ACTION_BOUND,
)
register_fast_path(
    "compile",
    "snapflow.inference.compile:compile_default",
    "torch.compile the prefix pass and the one-pass velocity",
)
register_fast_path(
    "compile-reduce-overhead",
    "snapflow.inference.compile:compile_reduce_overhead",
    "as compile, both captured as CUDA graphs on a GPU",
)
register_fast_path(
    "compile-max-autotune",
    "snapflow.inference.compile:compile_max_autotune",
    "as compile, with kernels autotuned: a long first call",
)


__all__ = ["FastPath", "FAST_PATHS", "register_fast_path", "fast_path", "apply_fast_path"]
