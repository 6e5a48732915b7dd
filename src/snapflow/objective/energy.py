"""SnapFlow with a set-level energy term: a one-step student that keeps the modes of a multimodal field.

SnapFlow's consistency rows regress each jump F(x_1, s=0, t=1) onto a K-step Euler average of the teacher's
velocities. With few steps that target blurs a field with several modes, and a regression of it lands between them.
This objective keeps those rows and adds, for every one-step row's observation, M - 1 more jumps from independent
noises in the same gradient pass (:class:`~snapflow.objective.base.SetRows`), and scores the M one-step samples
X_j = x_1^j - F(x_1^j, 0, 1) of that observation against its demonstration a by the energy score

    ES = mean_j || X_j - a || - 1 / (2 M (M - 1)) sum_{j != k} || X_j - X_k ||,

a strictly proper scoring rule: its expectation over a ~ p(a | c) is least when the samples are drawn from p(a | c)
itself, so one demonstration per observation suffices and no teacher pass is spent on it. The loss is

    L = alpha * L_FM + (1 - alpha) * (lambda * L_SC + energy_weight * mean_rows ES).

The set term rewards spread that lands on the data (the second sum) and the consistency term keeps the jump on its
teacher's flow: together the student keeps its teacher's modes where the two-step target alone averages them. At
lambda 0 the consistency target's K no-grad teacher passes are skipped, and the energy term trains the jump alone.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any

import torch
from torch import Tensor

from snapflow.errors import InvalidInputError
from snapflow.objective.base import OneStepRows, SetRows, draw_device
from snapflow.objective.snapflow import SnapFlowObjective
from snapflow.protocol import Context, FlowPolicy, draw_flow_noise

#: the floor under a squared distance before its root, so that two equal samples still have a finite gradient
NORM_FLOOR = 1e-12


def weighted_norm(difference: Tensor, weights: Tensor | None) -> Tensor:
    """Euclidean norm over every dimension but the first ones that ``weights`` lacks: sqrt(sum w d^2 + floor)."""
    squared = difference.pow(2) if weights is None else weights * difference.pow(2)
    return (squared.sum(-1) + NORM_FLOOR).sqrt()


def energy_score(samples: Tensor, reference: Tensor, weights: Tensor | None = None) -> Tensor:
    """Each row's energy score of its ``samples`` (R, M, D) against its one ``reference`` (R, D): mean_j |X_j - y|
    minus half the mean distance between distinct samples; ``weights`` (R, D) weigh the entries (padding: 0).
    Lower is better; (R,)."""
    count = samples.shape[1]
    if count < 2:
        raise ValueError(f"an energy score needs at least two samples a row, got {count}")
    row_weights = None if weights is None else weights[:, None, :]
    to_reference = weighted_norm(samples - reference[:, None, :], row_weights).mean(1)
    pair_weights = None if weights is None else weights[:, None, None, :]
    between = weighted_norm(samples[:, :, None, :] - samples[:, None, :, :], pair_weights)
    spread = (between.sum((1, 2)) - between.diagonal(dim1=1, dim2=2).sum(1)) / (count * (count - 1))
    return to_reference - spread / 2


@dataclass(frozen=True)
class EnergySnapFlowObjective(SnapFlowObjective):
    """SnapFlow's consistency rows plus an energy score of ``energy_samples`` one-step samples per observation.

    Args:
        alpha, consistency_weight, time_sampler, teacher_velocity_clamp, teacher_velocity, target_steps: as for
            :class:`~snapflow.objective.snapflow.SnapFlowObjective` (its consistency term is kept as it is).
        energy_weight: the energy term's weight, beside lambda, within the one-step branch.
        energy_samples: M >= 2, one-step samples per observation (the row's own jump and M - 1 more, from independent
            noises); each adds one row per one-step row to the gradient pass, and no teacher pass.

    At lambda 0 the consistency target is not computed: the step spends no teacher pass at all.
    """

    energy_weight: float = 16.0
    energy_samples: int = 3
    intermediate_jumps: float = field(default=0.0, init=False)  # every jump from noise, as the energy term's

    def __post_init__(self) -> None:
        super().__post_init__()
        if not isinstance(self.energy_samples, int) or self.energy_samples < 2:
            raise InvalidInputError(f"energy_samples must be an integer >= 2, got {self.energy_samples!r}")
        if self.energy_weight < 0:
            raise InvalidInputError(f"energy_weight must be non-negative, got {self.energy_weight}")

    @property
    def trains_jump(self) -> bool:
        """Whether the jump is trained: by lambda or by the energy term."""
        return self.consistency_weight > 0 or self.energy_weight > 0

    def one_step_rows(
        self,
        policy: FlowPolicy,
        observation: Any,
        context: Context,
        actions: Tensor,
        noise: Tensor,
        generator: torch.Generator | None,
        progress: float,
    ) -> OneStepRows:
        """SnapFlow's jumps 1 -> 0 and their targets, and M - 1 more jumps of each row's observation from new noise
        (sample j of row r at extra row (j - 1) R + r)."""
        rows = super().one_step_rows(policy, observation, context, actions, noise, generator, progress)
        count = noise.shape[0]
        shape = ((self.energy_samples - 1) * count, *noise.shape[1:])
        more = draw_flow_noise(policy, shape, generator, draw_device(generator, noise.device)).to(noise)
        ones = torch.ones(shape[0], device=noise.device)
        return replace(rows, extra=SetRows(more, ones, torch.zeros_like(ones), self.energy_samples - 1))

    def set_loss(
        self, rows: OneStepRows, prediction: Tensor, extra: Tensor, actions: Tensor, weights: Tensor | None
    ) -> Tensor:
        """``energy_weight`` times the mean energy score of each observation's M one-step samples x_1 - F."""
        if rows.extra is None:
            raise ValueError("the energy term scores the extra one-step rows its one_step_rows returns")
        count = actions.shape[0]
        jumps = torch.cat([rows.x - prediction, rows.extra.x - extra])  # (M R, ...), sample-major
        samples = jumps.reshape(self.energy_samples, count, -1).transpose(0, 1)
        flat_weights = None if weights is None else weights.reshape(count, -1)
        return self.energy_weight * energy_score(samples, actions.reshape(count, -1), flat_weights).mean()


__all__ = ["EnergySnapFlowObjective", "energy_score"]
