"""Latency of chunk generation at batch 1, split into the prefix (encode) and the denoising passes.

Every quantity (the prefix, and per sampling mode the denoising passes alone and end-to-end generation) is
timed after a warm-up, many times, round-robin: repeat r times each quantity once, in an order that rotates
with r, so that drift of a shared machine spreads over all of them instead of biasing whichever came last.
Medians and P90; CUDA events on a GPU, a monotonic clock elsewhere.
"""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from typing import Any

import torch

from snapflow.flow.modes import SamplingMode
from snapflow.flow.solver import euler_sample, sample_actions
from snapflow.protocol import FlowPolicy


def _time_once_ms(function: Callable[[], Any], device: torch.device) -> float:
    if device.type == "cuda":
        start, end = torch.cuda.Event(enable_timing=True), torch.cuda.Event(enable_timing=True)
        start.record()
        function()
        end.record()
        torch.cuda.synchronize()
        return start.elapsed_time(end)
    began = time.perf_counter()
    function()
    return (time.perf_counter() - began) * 1e3


@dataclass(frozen=True)
class Timing:
    """Median and P90 milliseconds of ``repeats`` timed calls."""

    median_ms: float
    p90_ms: float
    repeats: int

    @classmethod
    def of(cls, samples: list[float]) -> Timing:
        ordered = sorted(samples)
        return cls(statistics.median(ordered), ordered[min(int(0.9 * len(ordered)), len(ordered) - 1)], len(ordered))


@dataclass
class LatencyRow:
    """One sampling mode: denoising passes alone and end-to-end, their ratio, and speedups over a reference row.
    ``prefix`` is the row's own prefix time where rows come from different policies."""

    nfe: int
    denoising: Timing
    end_to_end: Timing
    prefix: Timing | None = None
    denoising_speedup: float = 1.0
    end_to_end_speedup: float = 1.0

    @property
    def per_pass_ms(self) -> float:
        return self.denoising.median_ms / self.nfe

    @property
    def denoising_share(self) -> float:
        return self.denoising.median_ms / self.end_to_end.median_ms

    def to_dict(self) -> dict[str, Any]:
        row = {"prefix": asdict(self.prefix)} if self.prefix is not None else {}
        return {
            **row,
            "nfe": self.nfe,
            "denoising": asdict(self.denoising),
            "per_pass_ms": self.per_pass_ms,
            "end_to_end": asdict(self.end_to_end),
            "denoising_share": self.denoising_share,
            "denoising_speedup": self.denoising_speedup,
            "end_to_end_speedup": self.end_to_end_speedup,
        }


@dataclass
class LatencyReport:
    """What :func:`measure_latency` measured of one policy: its prefix and every mode (speedups over the first)."""

    prefix: Timing
    modes: dict[str, LatencyRow]
    warmup: int
    repeats: int
    device: str

    def marginal_per_pass_ms(self, name: str) -> float:
        """Mode ``name``'s marginal cost of a pass: its end-to-end median minus the prefix's, over its NFE (what a
        pass adds to a chunk, fixed costs such as the prefix's copy out of a graph included, unlike the denoising
        passes timed alone)."""
        row = self.modes[name]
        prefix = row.prefix or self.prefix
        return (row.end_to_end.median_ms - prefix.median_ms) / row.nfe

    def to_dict(self) -> dict[str, Any]:
        return {
            "prefix": asdict(self.prefix),
            "modes": {
                name: {**row.to_dict(), "marginal_per_pass_ms": self.marginal_per_pass_ms(name)}
                for name, row in self.modes.items()
            },
            "warmup": self.warmup,
            "repeats": self.repeats,
            "device": self.device,
        }


def time_round_robin(
    functions: dict[str, Callable[[], Any]], device: torch.device, warmup: int, repeats: int
) -> dict[str, Timing]:
    """Median / P90 milliseconds of each function, timed in rotating order after ``warmup`` calls of each."""
    if repeats < 1 or warmup < 0:
        raise ValueError(f"need repeats >= 1 and warmup >= 0, got {repeats} and {warmup}")
    names = list(functions)
    for _ in range(warmup):
        for name in names:
            functions[name]()
    samples: dict[str, list[float]] = {name: [] for name in names}
    for repeat in range(repeats):
        shift = repeat % len(names)
        for name in names[shift:] + names[:shift]:
            samples[name].append(_time_once_ms(functions[name], device))
    return {name: Timing.of(values) for name, values in samples.items()}


@torch.inference_mode()
def measure_latency(
    policy: FlowPolicy,
    observation: Any,
    noise: torch.Tensor,
    modes: list[SamplingMode],
    warmup: int = 10,
    repeats: int = 50,
) -> LatencyReport:
    """Prefix, denoising-only (and per pass) and end-to-end time per chunk for each mode, the denoising share of
    end-to-end time, and every speedup over the first mode (the reference, normally the 10-step teacher)."""
    device = noise.device
    context = policy.encode(observation)

    def velocity(x: torch.Tensor, t: torch.Tensor, s: torch.Tensor) -> torch.Tensor:
        return policy.velocity(x, t, s, context)

    functions: dict[str, Callable[[], Any]] = {"prefix": lambda: policy.encode(observation)}
    for mode in modes:
        functions[f"{mode.name}/denoising"] = lambda mode=mode: euler_sample(velocity, noise, mode)
        functions[f"{mode.name}/end_to_end"] = lambda mode=mode: sample_actions(policy, observation, noise, mode)
    timed = time_round_robin(functions, device, warmup, repeats)
    rows = {
        mode.name: LatencyRow(mode.num_steps, timed[f"{mode.name}/denoising"], timed[f"{mode.name}/end_to_end"])
        for mode in modes
    }
    return LatencyReport(timed["prefix"], add_speedups(rows), warmup, repeats, str(device))


def add_speedups(rows: dict[str, LatencyRow]) -> dict[str, LatencyRow]:
    """Set the denoising and end-to-end speedups of every row over the first one (the reference)."""
    reference = next(iter(rows.values()))
    for row in rows.values():
        row.denoising_speedup = reference.denoising.median_ms / row.denoising.median_ms
        row.end_to_end_speedup = reference.end_to_end.median_ms / row.end_to_end.median_ms
    return rows


__all__ = ["Timing", "LatencyRow", "LatencyReport", "measure_latency", "add_speedups", "time_round_robin"]
