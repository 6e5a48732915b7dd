"""Latency of chunk generation at batch 1, split into the prefix (encode) and the denoising passes.

Every quantity (the prefix, and per sampling mode the denoising passes alone and end-to-end generation) is
timed after a warm-up, many times, round-robin: repeat r times each quantity once, in an order that rotates
with r, so that drift of a shared machine spreads over all of them instead of biasing whichever came last.
Medians and P90; CUDA events on a GPU, a monotonic clock elsewhere.
"""

from __future__ import annotations

import platform
import statistics
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import torch

from snapflow.flow.solver import SamplingMode, euler_sample, sample_actions
from snapflow.protocol import FlowPolicy


def machine() -> dict[str, Any]:
    """The machine the figures come from, named."""
    cpu = platform.processor() or platform.machine()
    try:
        cpu = next(line.split(":", 1)[1].strip() for line in Path("/proc/cpuinfo").read_text().splitlines() if line.startswith("model name"))
    except (OSError, StopIteration):
        pass
    return {"cpu": cpu, "threads": torch.get_num_threads(), "gpu": torch.cuda.get_device_name(0) if torch.cuda.is_available() else None,
            "torch": torch.__version__, "python": platform.python_version()}


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


def _summary(samples: list[float]) -> dict[str, float]:
    ordered = sorted(samples)
    return {"median_ms": statistics.median(ordered), "p90_ms": ordered[min(int(0.9 * len(ordered)), len(ordered) - 1)],
            "repeats": len(ordered)}


def time_round_robin(functions: dict[str, Callable[[], Any]], device: torch.device, warmup: int, repeats: int) -> dict[str, dict[str, float]]:
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
    return {name: _summary(values) for name, values in samples.items()}


@torch.inference_mode()
def measure_latency(
    policy: FlowPolicy, observation: Any, noise: torch.Tensor, modes: list[SamplingMode], warmup: int = 10, repeats: int = 50,
) -> dict[str, Any]:
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
    result: dict[str, Any] = {"prefix": timed["prefix"], "modes": {}, "warmup": warmup, "repeats": repeats, "device": str(device)}
    for mode in modes:
        denoise, end_to_end = timed[f"{mode.name}/denoising"], timed[f"{mode.name}/end_to_end"]
        result["modes"][mode.name] = {
            "nfe": mode.num_steps, "denoising": denoise, "per_pass_ms": denoise["median_ms"] / mode.num_steps,
            "end_to_end": end_to_end, "denoising_share": denoise["median_ms"] / end_to_end["median_ms"],
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


__all__ = ["machine", "measure_latency", "add_speedups", "time_round_robin"]
