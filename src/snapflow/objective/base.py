"""What every distillation objective here shares: a batch split into flow-matching and one-step rows.

The first ``round(alpha * B)`` rows keep training the policy's own flow-matching (FM) velocity
F(x_t, s=t, t) on eps - a, which is also what the one-step targets are built from. The other rows are
"one-step" rows: each method chooses their inputs (x, t, s) and a regression target computed without
gradient, and one gradient pass covers both kinds of rows:

    L = alpha * L_FM + (1 - alpha) * (lambda * mean_rows(w * || F(x, t, s) - target ||^2) + L_set).

A method may add more one-step rows to the same pass (:class:`SetRows`: more samples of a row's observation, from
other noises) and score them, with the one-step rows, by a set-level term L_set (:meth:`TwoBranchObjective.set_loss`).

A policy whose chunks hold padding (:class:`snapflow.protocol.PaddedActions`) has both means taken over the
entries it weighs only: L_FM over all the FM rows' weighted entries (as GR00T's own loss), each one-step row's
error over its own.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import Any, ClassVar

import torch
from torch import Tensor

from snapflow.errors import InvalidInputError
from snapflow.flow.path import conditional_velocity, interpolate
from snapflow.flow.time_sampling import TimeSampler
from snapflow.protocol import Context, FlowPolicy, PaddedActions, draw_flow_noise, index_batch, map_tensors


def draw_device(generator: torch.Generator | None, device: torch.device) -> torch.device:
    """Where a random draw must happen: on the generator's device when one is given (the trainer's is a CPU
    generator, so that a resumed run draws the same numbers on any accelerator)."""
    return generator.device if generator is not None else device


def uniform(count: int, generator: torch.Generator | None, like: Tensor) -> Tensor:
    """``count`` draws from U(0, 1) with the device and dtype of ``like``, reproducible from ``generator``."""
    return torch.rand(count, generator=generator, device=draw_device(generator, like.device)).to(like)


def weighted_mean(squared: Tensor, weights: Tensor | None) -> Tensor:
    """The mean of ``squared`` over the entries ``weights`` (same shape) weighs; a plain mean where None."""
    if weights is None:
        return squared.mean()
    return (weights * squared).sum() / weights.sum().clamp_min(WEIGHT_FLOOR)


def row_means(squared: Tensor, weights: Tensor | None) -> Tensor:
    """Each row's :func:`weighted_mean` of ``squared`` (B, ...): (B,); a row that weighs no entry has 0."""
    if weights is None:
        return squared.flatten(1).mean(1)
    weights = weights.flatten(1)
    return (weights * squared.flatten(1)).sum(1) / weights.sum(1).clamp_min(WEIGHT_FLOOR)


WEIGHT_FLOOR = 1e-12  # a denominator's floor: a chunk that weighs nothing has a zero numerator too


@dataclass(frozen=True)
class LossOutput:
    """The total loss (with graph) and its parts (detached, for logging)."""

    loss: Tensor
    flow_matching_loss: Tensor
    consistency_loss: Tensor
    num_flow_matching: int
    num_consistency: int


@dataclass(frozen=True)
class SetRows:
    """More one-step rows in the same gradient pass, without a regression target of their own: ``repeats`` more samples
    of every one-step row's observation, each from its own input ``x`` (sample j of one-step row r at row j R + r)."""

    x: Tensor
    t: Tensor
    s: Tensor
    repeats: int


@dataclass(frozen=True)
class OneStepRows:
    """Inputs and no-grad regression target of a method's one-step rows.

    ``target`` None: no regression term (lambda 0), so no teacher pass is spent on one and L_SC is logged as 0.
    ``weight`` (rows,) scales each row's squared error e; ``adaptive_power`` p > 0 further divides it by
    sg(e + ADAPTIVE_EPSILON) ** p, MeanFlow's adaptive loss weighting (p = 1 makes each row's loss ~ 1 - c / e).
    ``extra`` holds more rows for a set-level term (:meth:`TwoBranchObjective.set_loss`).
    """

    x: Tensor
    t: Tensor
    s: Tensor
    target: Tensor | None
    weight: Tensor | None = None
    adaptive_power: float = 0.0
    extra: SetRows | None = None


ADAPTIVE_EPSILON = 1e-3


class TwoBranchObjective(ABC):
    """Base of SnapFlow and the one-step baselines; ``alpha = 1`` is plain flow matching.

    Subclasses are dataclasses with the fields ``alpha``, ``consistency_weight`` (lambda) and
    ``time_sampler`` (the policy's own FM training-time distribution), and implement ``one_step_rows``.
    """

    alpha: float
    consistency_weight: float
    time_sampler: TimeSampler
    #: whether it keeps a copy of the whole policy (an EMA target network), which a sharded student cannot split
    copies_policy: ClassVar[bool] = False

    def _check_weights(self) -> None:
        if not 0.0 <= self.alpha <= 1.0:
            raise InvalidInputError(f"alpha must be in [0, 1], got {self.alpha}")
        if self.consistency_weight < 0:
            raise InvalidInputError(f"consistency_weight (lambda) must be non-negative, got {self.consistency_weight}")

    @property
    def trains_jump(self) -> bool:
        """Whether a one-step row's loss is weighted at all (lambda > 0, or a set-level term's weight)."""
        return self.consistency_weight > 0

    def num_flow_matching(self, batch_size: int) -> int:
        """Fixed FM share of a batch: round(alpha * B), keeping both branches present when 0 < alpha < 1."""
        if self.alpha in (0.0, 1.0):
            return int(self.alpha) * batch_size
        if batch_size < 2:
            raise InvalidInputError(
                f"0 < alpha < 1 needs batches of at least 2 samples to fill both branches, got {batch_size}"
            )
        return min(max(math.floor(self.alpha * batch_size + 0.5), 1), batch_size - 1)

    @abstractmethod
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
        """Inputs and target of the one-step rows, given their observation, context, actions and noise, at
        ``progress`` (the fraction of training done, for objectives with a schedule)."""

    def schedule(self, progress: float) -> dict[str, int]:
        """The scheduled settings in force at ``progress``, which the trainer logs; none by default."""
        return {}

    def set_loss(
        self, rows: OneStepRows, prediction: Tensor, extra: Tensor, actions: Tensor, weights: Tensor | None
    ) -> Tensor:
        """The set-level term L_set of an objective whose one-step rows hold ``extra`` rows, from the one-step rows'
        ``prediction``, the extra rows' (``extra``), the rows' ``actions`` and their entries' ``weights``."""
        raise ValueError(f"{type(self).__name__} returned extra one-step rows but scores none")

    def __call__(
        self,
        policy: FlowPolicy,
        observation: Any,
        actions: Tensor,
        *,
        noise: Tensor | None = None,
        time: Tensor | None = None,
        generator: torch.Generator | None = None,
        progress: float = 1.0,
    ) -> LossOutput:
        """Loss for one batch of ground-truth ``actions`` (B, ...).

        The first ``num_flow_matching(B)`` samples take the FM branch, the rest the one-step branch.
        ``noise`` (B, ...) and ``time`` (FM samples only) may be given; otherwise they are drawn, as is any
        randomness of the one-step rows, from ``generator``. ``progress`` is the fraction of training done
        (a schedule's last stage when not given).
        """
        batch = actions.shape[0]
        n_fm = self.num_flow_matching(batch)
        n_sc = batch - n_fm
        if noise is None:
            draw_on = draw_device(generator, actions.device)
            noise = draw_flow_noise(policy, actions.shape, generator, draw_on).to(actions.device, actions.dtype)
        elif noise.shape != actions.shape:
            raise ValueError(f"noise {tuple(noise.shape)} must match actions {tuple(actions.shape)}")
        if time is None:
            time = self.time_sampler(n_fm, device=draw_device(generator, actions.device), generator=generator).to(
                actions.device
            )
        elif time.shape != (n_fm,):
            raise ValueError(f"time must have shape ({n_fm},) for the FM samples, got {tuple(time.shape)}")
        fm_rows, sc_rows = slice(0, n_fm), slice(n_fm, batch)
        weights = policy.action_weights(observation) if isinstance(policy, PaddedActions) else None
        if weights is not None:
            weights = weights.to(actions).expand_as(actions)

        context = policy.encode(observation)
        x_in, t_in, s_in = (
            interpolate(actions[fm_rows], noise[fm_rows], time),
            time.to(actions.dtype),
            time.to(actions.dtype),
        )
        rows = None
        if n_sc:
            rows = self.one_step_rows(
                policy,
                index_batch(observation, sc_rows),
                index_batch(context, sc_rows),
                actions[sc_rows],
                noise[sc_rows],
                generator,
                progress,
            )
            x_in, t_in, s_in = (
                torch.cat([x_in, rows.x]),
                torch.cat([t_in, rows.t.to(t_in.dtype)]),
                torch.cat([s_in, rows.s.to(s_in.dtype)]),
            )
        if rows is not None and rows.extra is not None:  # each extra row on its one-step row's context
            x_in, t_in, s_in = (
                torch.cat([x_in, rows.extra.x]),
                torch.cat([t_in, rows.extra.t.to(t_in.dtype)]),
                torch.cat([s_in, rows.extra.s.to(s_in.dtype)]),
            )
            repeats = rows.extra.repeats  # the one-step rows' contexts tiled (a copy: on a CPU, cheaper than a gather)
            context = map_tensors(
                context, lambda tensor: torch.cat([tensor, tensor[sc_rows].repeat(repeats, *(1,) * (tensor.ndim - 1))])
            )
        prediction = policy.velocity(x_in, t_in, s_in, context)  # one gradient pass over every kind of row

        zero = prediction.new_zeros(())
        fm_loss = zero
        if n_fm:
            squared = (prediction[fm_rows] - conditional_velocity(actions[fm_rows], noise[fm_rows])).pow(2)
            fm_loss = weighted_mean(squared, None if weights is None else weights[fm_rows])
        sc_loss = zero
        if rows is not None and rows.target is not None:
            error = row_means((prediction[sc_rows] - rows.target).pow(2), None if weights is None else weights[sc_rows])
            weighted = error if rows.weight is None else rows.weight * error
            if rows.adaptive_power:
                weighted = weighted / (error.detach() + ADAPTIVE_EPSILON) ** rows.adaptive_power
            sc_loss = weighted.mean()
        loss = self.alpha * fm_loss + (1 - self.alpha) * self.consistency_weight * sc_loss
        if rows is not None and rows.extra is not None:
            sc_weights = None if weights is None else weights[sc_rows]
            set_term = self.set_loss(rows, prediction[sc_rows], prediction[batch:], actions[sc_rows], sc_weights)
            loss = loss + (1 - self.alpha) * set_term
        return LossOutput(loss, fm_loss.detach(), sc_loss.detach(), n_fm, n_sc)


__all__ = [
    "LossOutput",
    "OneStepRows",
    "SetRows",
    "TwoBranchObjective",
    "draw_device",
    "row_means",
    "uniform",
    "weighted_mean",
]
