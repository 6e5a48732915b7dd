"""A training step's batch under data parallelism: every process draws the step's whole batch (its indices, noise
and flow-matching times) from a generator of (seed, step), and trains on its own share of the rows, laid out as the
objective lays out a batch (flow-matching rows first); so P processes take the steps one process takes."""

from __future__ import annotations

from typing import TYPE_CHECKING

import torch
from torch import Tensor, nn

from snapflow.errors import InvalidInputError
from snapflow.objective.base import TwoBranchObjective
from snapflow.protocol import draw_flow_noise

if TYPE_CHECKING:
    from snapflow.training.trainer import ChunkSource


def step_generator(seed: int, process: int, step: int) -> torch.Generator:
    """The generator of step ``step`` on ``process`` (process 0's draws the step's global batch on every process)."""
    return torch.Generator().manual_seed(seed * 1_000_003 + process * 7_919 + step)


def share_of_batch(batch_size: int, processes: int) -> int:
    """The rows each of ``processes`` trains on in a step of ``batch_size`` (the global batch); refuses a batch that
    does not split evenly."""
    if batch_size % processes:
        raise InvalidInputError(
            f"the batch of {batch_size} training pairs a step does not split evenly over {processes} processes: "
            "give a --batch-size that is a multiple of the number of processes"
        )
    return batch_size // processes


def shard_rows(objective: TwoBranchObjective, batch_size: int, processes: int, process: int) -> tuple[Tensor, slice]:
    """The rows of a step's global draw that ``process`` trains on (its share of the flow-matching rows, then its
    share of the one-step rows: the objective's layout of a batch), and its slice of the flow-matching times. One
    process trains on every row, in order."""
    share = share_of_batch(batch_size, processes)
    flow_matching = objective.num_flow_matching(share)
    one_step = share - flow_matching
    first_one_step = processes * flow_matching
    rows = torch.cat(
        [
            torch.arange(process * flow_matching, (process + 1) * flow_matching),
            torch.arange(first_one_step + process * one_step, first_one_step + (process + 1) * one_step),
        ]
    )
    return rows, slice(process * flow_matching, (process + 1) * flow_matching)


def draw_batch(
    policy: nn.Module,
    objective: TwoBranchObjective,
    data: ChunkSource,
    batch_size: int,
    generator: torch.Generator,
    processes: int = 1,
    process: int = 0,
):
    """The batch of ``process`` (of ``processes``) in a step of ``batch_size`` pairs drawn from ``generator``: every
    process draws the whole step's indices, noise and times, and reads only its own rows' pairs."""
    rows, times = shard_rows(objective, batch_size, processes, process)
    indices = torch.randint(len(data), (batch_size,), generator=generator)
    observation, actions = data.batch(indices[rows])
    noise = draw_flow_noise(policy, (batch_size, *actions.shape[1:]), generator)[rows]
    time = objective.time_sampler(processes * objective.num_flow_matching(len(rows)), generator=generator)[times]
    return observation, actions, noise, time


__all__ = ["draw_batch", "shard_rows", "share_of_batch", "step_generator"]
