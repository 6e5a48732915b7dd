"""The flow-matching time distributions a built-in teacher may train on, declared once by name: what ``snapflow train
--time-distribution``, a sweep's ``train.time_distribution``, :class:`~snapflow.training.config.TrainConfig` and a
checkpoint's ``policy.json`` hold. Plain Python, read by the CLI before any torch is loaded;
:func:`snapflow.flow.time_sampling.time_sampler_for` draws from one.

A distribution is written ``NAME`` or ``NAME:VALUE`` (``uniform``, ``beta:1.5``, ``shift:4``). In this library's
convention t = 1 is the noise, so leaning toward noise means more times near 1.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from snapflow.errors import InvalidInputError


@dataclass(frozen=True)
class TimeDistributionKind:
    """One named distribution: the name of its one number (None: it takes none) and what it is, in one line."""

    name: str
    parameter: str | None
    summary: str


UNIFORM = "uniform"
#: every distribution a built-in teacher trains on, by name; ``uniform`` first, the default (the one every teacher
#: trained on before the choice existed, so their records and checkpoints stay what they were)
TIME_DISTRIBUTIONS: dict[str, TimeDistributionKind] = {
    kind.name: kind
    for kind in (
        TimeDistributionKind(UNIFORM, None, "t ~ U(0, 1), every time alike"),
        TimeDistributionKind(
            "beta",
            "A",
            "t = 0.001 + 0.999 Beta(A, 1), leaning toward noise for A > 1; beta:1.5 is LeRobot's pi0, pi0.5 and SmolVLA",
        ),
        TimeDistributionKind(
            "shift",
            "S",
            "beta:1.5 shifted toward noise by S, t -> S t / (1 + (S - 1) t): arXiv 2606.05737's, which takes S = 4",
        ),
    )
}


def time_distribution_help() -> str:
    """The choices in one sentence, for a flag's help."""
    return "; ".join(
        f"{kind.name}{'' if kind.parameter is None else ':' + kind.parameter} ({kind.summary})"
        for kind in TIME_DISTRIBUTIONS.values()
    )


def parse_time_distribution(text: object) -> tuple[str, float | None]:
    """``NAME`` or ``NAME:VALUE`` read into the name and its number (None where the distribution takes none);
    anything else an :class:`~snapflow.errors.InvalidInputError` in one line that lists the choices."""
    choices = ", ".join(
        kind.name if kind.parameter is None else f"{kind.name}:{kind.parameter}" for kind in TIME_DISTRIBUTIONS.values()
    )
    if not isinstance(text, str):
        raise InvalidInputError(f"a time distribution is written as text, one of {choices}; got {text!r}")
    name, colon, value = text.strip().partition(":")
    kind = TIME_DISTRIBUTIONS.get(name)
    if kind is None:
        raise InvalidInputError(f"unknown time distribution {text!r}; choose one of {choices}")
    if kind.parameter is None:
        if colon:
            raise InvalidInputError(f"the time distribution {name!r} takes no value, got {text!r}")
        return name, None
    try:
        number = float(value)
    except ValueError:
        raise InvalidInputError(f"{name}:{kind.parameter} needs a number {kind.parameter}, got {text!r}") from None
    if not (math.isfinite(number) and number > 0):
        raise InvalidInputError(f"{name}:{kind.parameter} takes a positive, finite {kind.parameter}, got {text!r}")
    return name, number


def canonical_time_distribution(text: object) -> str:
    """``text`` checked and written one way (``beta:1.50`` -> ``beta:1.5``, ``shift:4.0`` -> ``shift:4``), so that
    one distribution is one record and one cache key."""
    name, number = parse_time_distribution(text)
    if number is None:
        return name
    written = repr(number)
    return f"{name}:{written.removesuffix('.0')}"


__all__ = [
    "TIME_DISTRIBUTIONS",
    "UNIFORM",
    "TimeDistributionKind",
    "canonical_time_distribution",
    "parse_time_distribution",
    "time_distribution_help",
]
