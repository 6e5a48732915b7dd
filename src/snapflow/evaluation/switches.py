"""How smoothly an episode's chunks join: the action jump and the jerk at its chunk switches, beside the same measures
at every other step.

The closed-loop evaluator runs n_act actions of each chunk, with or without an inference delay
(:meth:`~snapflow.evaluation.closed_loop.ClosedLoopEvaluator.run`), so an episode's chunk switches are its steps
n_act, 2 n_act, ...: the step whose action is the first of a new chunk. At a switch k the jump is
``|a_k - a_{k-1}|`` and the jerk the third difference across it, ``|a_{k+1} - 3 a_k + 3 a_{k-1} - a_{k-2}|``
(Euclidean norms over the action's entries); a robot feels both at every switch.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from snapflow.errors import InvalidInputError
from snapflow.reporting.tables import markdown_table


def switch_steps(episode_steps: int, n_act: int) -> list[int]:
    """The steps of an episode of ``episode_steps`` actions whose action is the first of a new chunk."""
    if n_act < 1:
        raise InvalidInputError(f"n_act must be at least 1, got {n_act}")
    return list(range(n_act, episode_steps, n_act))


#: the measures of :class:`SwitchSmoothness`, each a mean over steps
MEASURES = ("jump_at_switches", "jump_elsewhere", "jerk_at_switches", "jerk_elsewhere")


@dataclass(frozen=True)
class SwitchSmoothness:
    """Mean jump and jerk at an episode's chunk switches and at its other steps (nan where there is none)."""

    switches: int
    jump_at_switches: float
    jump_elsewhere: float
    jerk_at_switches: float
    jerk_elsewhere: float

    def to_dict(self) -> dict[str, Any]:
        """As JSON holds it: nan (no such step) as None."""
        return {
            key: None if isinstance(value, float) and math.isnan(value) else value
            for key, value in asdict(self).items()
        }

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> SwitchSmoothness:
        return cls(**{key: math.nan if value is None else value for key, value in data.items()})


def mean_smoothness(parts: list[SwitchSmoothness]) -> SwitchSmoothness:
    """Several episodes' (or seeds') smoothness as one: the switches summed, each measure the mean of the parts' that
    have it."""
    if not parts:
        raise ValueError("no smoothness to average")
    means = {key: _mean([v for part in parts if not math.isnan(v := getattr(part, key))]) for key in MEASURES}
    return SwitchSmoothness(sum(part.switches for part in parts), **means)


#: what the tables of chunk switches say beneath them
SWITCHES_NOTE = (
    "At a switch k (the first action of a new chunk) the jump |a_k - a_k-1| and the jerk |a_k+1 - 3 a_k + 3 a_k-1 - "
    "a_k-2| of the executed (unnormalised) actions, the mean over each episode's switches, then over episodes; "
    "elsewhere: the same at every other step."
)


def markdown_switches(rows: dict[str, SwitchSmoothness]) -> str:
    """Each labelled row's jump and jerk at its chunk switches and at its other steps, as a Markdown table."""
    header = ["row", "switches", "jump at switches", "jump elsewhere", "jerk at switches", "jerk elsewhere"]
    measures = ("jump_at_switches", "jump_elsewhere", "jerk_at_switches", "jerk_elsewhere")
    cells = [[label, row.switches, *(f"{getattr(row, key):.4f}" for key in measures)] for label, row in rows.items()]
    return markdown_table(header, cells)


def _mean(values: list[float]) -> float:
    return float(np.mean(values)) if values else math.nan


def switch_smoothness(actions: np.ndarray, n_act: int) -> SwitchSmoothness:
    """The jump and jerk of the executed ``actions`` (steps, action width) at the chunk switches and elsewhere."""
    actions = np.asarray(actions, dtype=np.float64)
    if actions.ndim != 2:
        raise InvalidInputError(f"actions must be (steps, action width), got shape {actions.shape}")
    switches = set(switch_steps(len(actions), n_act))
    jumps = {k: float(np.linalg.norm(actions[k] - actions[k - 1])) for k in range(1, len(actions))}
    jerks = {
        k: float(np.linalg.norm(actions[k + 1] - 3 * actions[k] + 3 * actions[k - 1] - actions[k - 2]))
        for k in range(2, len(actions) - 1)
    }
    return SwitchSmoothness(
        len(switches),
        _mean([value for k, value in jumps.items() if k in switches]),
        _mean([value for k, value in jumps.items() if k not in switches]),
        _mean([value for k, value in jerks.items() if k in switches]),
        _mean([value for k, value in jerks.items() if k not in switches]),
    )


__all__ = [
    "SWITCHES_NOTE",
    "SwitchSmoothness",
    "markdown_switches",
    "mean_smoothness",
    "switch_smoothness",
    "switch_steps",
]
