"""What every opened policy answers, whatever it came from (a built-in checkpoint, a LeRobot folder or hub id, an
export of either): the policy and its processor, whether it was distilled, whether it is an export and of which
format, and so which sampling modes it runs; the others are refused by name before anything runs."""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch
from torch import Tensor, nn

from snapflow.errors import InvalidInputError
from snapflow.flow.modes import SNAPFLOW_1, TEACHER_10, SamplingMode
from snapflow.inference.formats import export_record


class CheckpointError(InvalidInputError):
    """A policy that is missing, corrupt, does not match what it is loaded into, or is asked for what it cannot
    honestly run (a jump mode of a teacher, another mode of an export): the reason and what to do instead."""


@dataclass
class BenchSubject:
    """A policy with its batch-1 inputs, as ``snapflow bench`` times it; ``one_step`` is its 1-NFE mode: SnapFlow's
    jump, or the naive step for a policy never distilled (no trained target-time embedding)."""

    name: str
    policy: nn.Module
    observation: Any
    noise: Tensor
    #: the flow-matching times it trains on (the cost of a distillation step draws them)
    time_sampler: Any
    details: dict[str, Any] = field(default_factory=dict)
    one_step: SamplingMode = SNAPFLOW_1
    #: the only modes the policy runs (an ONNX export runs its one jump), or None for any
    only_modes: tuple[SamplingMode, ...] | None = None
    #: the dtype it was asked to run in (what runs, as timed, is in the report's ``dtype``: a policy may keep layers
    #: in float32, and a fast path may change them)
    dtype: torch.dtype = torch.float32
    #: the number of steps its own sampler takes (a LeRobot policy's, as configured), timed beside the teacher modes
    own_steps: int | None = None
    #: the paper's figures for its type (A800, end to end, batch 1, ms), where the paper gives them
    paper_latency: dict[str, float] | None = None


def parameter_count(module: nn.Module) -> int:
    """How many parameters ``module`` holds."""
    return sum(parameter.numel() for parameter in module.parameters())


class OpenedPolicy(ABC):
    """The one loaded-policy protocol (see :func:`snapflow.sources.open_policy`)."""

    path: Path
    policy: Any  # a FlowPolicy
    processor: Any  # raw observations in, model inputs out; actions to and from the model's scale
    #: the share of each task's demonstration episodes its training held out (0 when unknown)
    val_fraction: float

    @property
    @abstractmethod
    def policy_type(self) -> str:
        """Its policy type's registered name (a built-in policy's, or LeRobot's ``smolvla``, ``snapflow_smolvla``, ...)."""

    @property
    @abstractmethod
    def distilled(self) -> bool:
        """Whether it was SnapFlow-distilled (a student), so that its jump modes (``snapflow-N``) mean something."""

    @property
    @abstractmethod
    def description(self) -> dict[str, Any]:
        """What it says of itself on disk (a checkpoint's ``policy.json``, a LeRobot folder's snapflow marker); an
        export keeps its format's record there under the format's name."""

    @property
    def export(self) -> dict[str, Any] | None:
        """The record of the export this is (its format's name under ``format``, its source, ...), or None."""
        found = export_record(self.description)
        return None if found is None else {"format": found[0].name, **found[1]}

    @property
    @abstractmethod
    def distill_command(self) -> str:
        """The command that would distil it, for the refusal of a jump mode on a teacher."""

    @abstractmethod
    def export_to(self, output: str | Path, format: str) -> dict[str, Any]:
        """Export this student's one jump in ``format`` (see :mod:`snapflow.inference.formats`) to the folder
        ``output``, which then opens as this policy's export; returns the format's record."""

    @property
    @abstractmethod
    def time_sampler(self) -> Any:
        """The flow-matching times it trains on (a :class:`~snapflow.flow.time_sampling.TimeSampler`): what its
        distillation and the cost of its training step use."""

    @abstractmethod
    def bench_subject(
        self, name: str, device: torch.device | str = "cpu", dtype: torch.dtype = torch.float32
    ) -> BenchSubject:
        """This policy on ``device`` in ``dtype`` with an example batch-1 observation (made by its own processor: the
        values do not change the timing) and fixed noise, named ``name``: what ``snapflow bench`` times."""

    @property
    def training_data(self) -> dict[str, Any]:
        """What its training recorded of its demonstrations (``env``, ``path``, ``val_fraction``), where it did."""
        return {}

    def held_out_share(self, given: float | None = None) -> float:
        """The share of each task's demonstration episodes its training held out: ``given`` where given (a trainer
        that records none, such as lerobot-train), else its own record."""
        return self.val_fraction if given is None else given

    @property
    def known_prefix_delay(self) -> int:
        """The most actions of a previous chunk it was distilled to be given (``DistillSettings.rtc_max_delay``; 0:
        none): how long an inference delay real-time chunking ``trained`` may run it under."""
        return 0

    @property
    def exported(self) -> bool:
        return self.export is not None

    @property
    def own_steps(self) -> int:
        """How many Euler steps its own sampler takes a chunk: what the bare ``teacher`` mode means for it (ten for
        the built-in policies; a LeRobot type's own field)."""
        return TEACHER_10.num_steps

    def resolve_mode(self, mode: SamplingMode) -> SamplingMode:
        """``mode`` as this policy samples it (``teacher`` at :attr:`own_steps`), refused where it cannot
        honestly run it (:meth:`check_mode`)."""
        resolved = mode.with_own_steps(self.own_steps)
        self.check_mode(resolved)
        return resolved

    def check_mode(self, mode: SamplingMode) -> None:
        """Refuse ``snapflow-N`` on a policy never distilled: without a trained target-time embedding the jump is the
        naive step, which would be reported under SnapFlow's name. Refuse any mode but ``snapflow-1`` on an export:
        its graph holds that one jump."""
        if self.export is not None and mode != SNAPFLOW_1:
            raise CheckpointError(
                f"{self.path} is a {self.export['format']} export of a one-step student: it runs snapflow-1 only; "
                f"for {mode.name}, use the policy it was exported from ({self.export['source']})"
            )
        if mode.jump and not self.distilled:
            raise CheckpointError(
                f"{self.path} is not SnapFlow-distilled (a flow-matching teacher): {mode.name} would be the naive "
                f"step under SnapFlow's name; use teacher-N or naive, or distill it first ({self.distill_command})"
            )


__all__ = ["BenchSubject", "OpenedPolicy", "CheckpointError", "parameter_count"]
