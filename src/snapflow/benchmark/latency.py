"""Latency of chunk generation at batch 1, split into the prefix (encode) and the denoising passes.

Medians and P90 over many repeats after a warm-up; CUDA events on a GPU, a monotonic clock elsewhere.
"""

from __future__ import annotations

import statistics
import time
from typing import Any, Callable

import torch

from snapflow.flow.solver import SamplingMode, euler_sample, sample_actions
from snapflow.protocol import FlowPolicy


def _time_ms(function: Callable[[], Any], device: torch.device, warmup: int, repeats: int) -> list[float]:
    for _ in range(warmup):
        function()
    samples = []
    for _ in range(repeats):
        if device.type == "cuda":
            start, end = torch.cuda.Event(enable_timing=True), torch.cuda.Event(enable_timing=True)
            start.record()
            function()
            end.record()
            torch.cuda.synchronize()
            samples.append(start.elapsed_time(end))
        else:
            began = time.perf_counter()
            function()
            samples.append((time.perf_counter() - began) * 1e3)
    return samples


def _summary(samples: list[float]) -> dict[str, float]:
    ordered = sorted(samples)
    return {"median_ms": statistics.median(ordered), "p90_ms": ordered[min(int(0.9 * len(ordered)), len(ordered) - 1)], "repeats": len(ordered)}


@torch.no_grad()
def measure_latency(
    policy: FlowPolicy, observation: Any, noise: torch.Tensor, modes: list[SamplingMode], warmup: int = 10, repeats: int = 50,
) -> dict[str, Any]:
    """Prefix, denoising-only and end-to-end time per chunk for each mode, and speedups over the first mode."""
    device = noise.device
    context = policy.encode(observation)
    velocity = lambda x, t, s: policy.velocity(x, t, s, context)  # noqa: E731
    result: dict[str, Any] = {"prefix": _summary(_time_ms(lambda: policy.encode(observation), device, warmup, repeats)), "modes": {}}
    for mode in modes:
        denoise = _summary(_time_ms(lambda mode=mode: euler_sample(velocity, noise, mode), device, warmup, repeats))
        end_to_end = _summary(_time_ms(lambda mode=mode: sample_actions(policy, observation, noise, mode), device, warmup, repeats))
        result["modes"][mode.name] = {
            "nfe": mode.num_steps, "denoising": denoise, "end_to_end": end_to_end,
            "denoising_share": denoise["median_ms"] / end_to_end["median_ms"],
        }
    add_speedups(result["modes"])
    return result


def add_speedups(entries: dict[str, dict[str, Any]]) -> dict[str, dict[str, Any]]:
    """Add denoising and end-to-end speedups of every entry over the first one (the reference)."""
    reference = next(iter(entries.values()))
    for entry in entries.values():
        entry["denoising_speedup"] = reference["denoising"]["median_ms"] / entry["denoising"]["median_ms"]
        entry["end_to_end_speedup"] = reference["end_to_end"]["median_ms"] / entry["end_to_end"]["median_ms"]
    return entries


__all__ = ["measure_latency", "add_speedups"]
