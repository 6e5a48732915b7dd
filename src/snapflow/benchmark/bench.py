"""``snapflow bench``: batch-1 latency of one policy at NFE 10, 5, 2 and 1, with the fast path and a profile
(the report it makes: :mod:`snapflow.benchmark.report`).

One step is what deployment runs: the prefix encoded once per chunk, then one pass of the action expert. Optionally
the policy runs a registered fast path (:mod:`snapflow.inference.fast_paths`: ``deploy``, the recommended one,
``compile-reduce-overhead`` capturing CUDA graphs on a GPU, ...): its first chunk is timed from its application
(compilation included) and its actions compared with the eager policy's. The policy may run in bfloat16 / float16.
The profile of the one-step path shows where its time goes.
"""

from __future__ import annotations

import functools
import time

import torch

from snapflow.benchmark.latency import Timing, measure_latency, time_round_robin
from snapflow.benchmark.report import BenchReport, FirstChunk, OneStepProfile, Throughput
from snapflow.benchmark.subjects import BenchSubject, parameter_dtypes, parameter_totals
from snapflow.flow.modes import SamplingMode
from snapflow.flow.solver import sample_actions
from snapflow.inference.fast_paths import FAST_PATHS, apply_fast_path
from snapflow.protocol import map_tensors
from snapflow.reporting.files import recorded_path
from snapflow.reporting.machine import machine

# the teacher's step counts timed before the subject's one-step mode
TEACHER_MODES = (SamplingMode(10, jump=False), SamplingMode(5, jump=False), SamplingMode(2, jump=False))


@torch.inference_mode()
def profile_one_step(subject: BenchSubject, calls: int = 20) -> OneStepProfile:
    """torch.profiler's view of ``calls`` one-step generations."""
    from torch.profiler import ProfilerActivity, profile

    device = subject.noise.device
    activities = [ProfilerActivity.CPU] + ([ProfilerActivity.CUDA] if device.type == "cuda" else [])
    with profile(activities=activities, acc_events=True) as profiler:
        began = time.perf_counter()
        for _ in range(calls):
            sample_actions(subject.policy, subject.observation, subject.noise, subject.one_step)
        if device.type == "cuda":
            torch.cuda.synchronize()
        wall_ms = (time.perf_counter() - began) * 1e3 / calls
    averages = profiler.key_averages()
    table = averages.table(
        sort_by="self_cuda_time_total" if device.type == "cuda" else "self_cpu_time_total", row_limit=25
    )
    # leaf operators (aten::*) do the arithmetic; their self time against the wall time bounds the overhead
    operator_ms = sum(event.self_cpu_time_total for event in averages if event.key.startswith("aten::")) / 1e3 / calls
    return OneStepProfile(table, calls, wall_ms, operator_ms, max(0.0, 1 - operator_ms / wall_ms))


def _repeat_first_row(tensor: torch.Tensor, size: int) -> torch.Tensor:
    return tensor[:1].expand(size, *tensor.shape[1:]).clone()


@torch.inference_mode()
def measure_throughput(
    subject: BenchSubject, modes: tuple[SamplingMode, ...], batch_sizes: tuple[int, ...], warmup: int, repeats: int
) -> Throughput:
    """End-to-end time of each mode at each batch size (the batch-1 observation repeated), timed round-robin
    within a batch size."""
    timings: dict[int, dict[str, Timing]] = {}
    for size in batch_sizes:
        observation = map_tensors(subject.observation, functools.partial(_repeat_first_row, size=size))
        noise = _repeat_first_row(subject.noise, size)
        functions = {
            mode.name: functools.partial(sample_actions, subject.policy, observation, noise, mode) for mode in modes
        }
        timings[size] = time_round_robin(functions, noise.device, warmup, repeats)
    return Throughput(timings)


@torch.inference_mode()
def one_step_actions(subject: BenchSubject) -> torch.Tensor:
    """The subject's one-step actions on its own inputs, in float32: what a fast path is measured against."""
    return sample_actions(subject.policy, subject.observation, subject.noise, subject.one_step).float()


# torch.compile's counters a first chunk reads: the graphs it made, and its on-disk cache's hits and misses
_FIRST_CHUNK_COUNTERS = (
    ("stats", "unique_graphs"),
    ("inductor", "fxgraph_cache_hit"),
    ("inductor", "fxgraph_cache_miss"),
)


def time_first_chunk(subject: BenchSubject, fast_path: str) -> FirstChunk:
    """Apply ``fast_path`` to the subject's policy and time its first one-step chunk (compilation and graph capture
    included) against the eager policy's chunk on the same inputs; count the graphs torch.compile made for it and
    how many of them its on-disk cache held (``$TORCHINDUCTOR_CACHE_DIR``, else torch's default folder)."""
    from torch._dynamo.utils import counters
    from torch._inductor.runtime.cache_dir_utils import cache_dir

    eager = one_step_actions(subject)
    before = {counter: counters[group][counter] for group, counter in _FIRST_CHUNK_COUNTERS}
    apply_fast_path(subject.policy, fast_path)
    began = time.perf_counter()
    fast = one_step_actions(subject)
    seconds = time.perf_counter() - began  # .float() has synchronised with the device
    graphs, hits, misses = (counters[group][counter] - before[counter] for group, counter in _FIRST_CHUNK_COUNTERS)
    return FirstChunk(
        seconds,
        (fast - eager).abs().max().item(),
        FAST_PATHS[fast_path].action_bound,
        graphs,
        hits,
        misses,
        recorded_path(cache_dir()),
    )


def run_bench(
    subject: BenchSubject,
    warmup: int = 10,
    repeats: int = 50,
    fast_path: str | None = None,
    profile: bool = True,
    modes: tuple[SamplingMode, ...] | None = None,
    batch_sizes: tuple[int, ...] = (),
) -> BenchReport:
    """Time ``subject`` at batch 1 at every mode (default: the teacher's 10, 5, 2 steps and the subject's one-step
    mode; the first is the reference of the speedups), the throughput of the first and last mode at
    ``batch_sizes``, and, optionally, profile its one-step mode, with the policy in fast path ``fast_path`` (a
    registered name, :func:`snapflow.inference.apply_fast_path`) where one is given: then its first chunk too."""
    own = (SamplingMode(subject.own_steps, jump=False),) if subject.own_steps else ()
    modes = modes or subject.only_modes or (*dict.fromkeys((*own, *TEACHER_MODES)), subject.one_step)
    first_chunk = time_first_chunk(subject, fast_path) if fast_path else None
    latency = measure_latency(subject.policy, subject.observation, subject.noise, list(modes), warmup, repeats)
    throughput = (
        measure_throughput(
            subject, tuple(dict.fromkeys((modes[0], modes[-1]))), batch_sizes, min(warmup, 3), max(3, repeats // 5)
        )
        if batch_sizes
        else None
    )
    profiled = profile_one_step(subject) if profile else None
    teacher, one_step = latency.modes[modes[0].name], latency.modes[modes[-1].name]
    # what one jump costs against one teacher step: phi_s's s path should add nothing measurable
    jump_ratio = one_step.per_pass_ms / teacher.per_pass_ms if modes[-1].jump and not modes[0].jump else None
    marginal_ratio = (
        latency.marginal_per_pass_ms(modes[-1].name) / latency.marginal_per_pass_ms(modes[0].name)
        if jump_ratio is not None
        else None
    )
    paper = subject.paper_latency  # the paper's A800 figures, end-to-end ms, batch 1
    return BenchReport(
        subject.name,
        subject.details,
        machine(),
        {
            "requested": str(subject.dtype).removeprefix("torch."),
            "inputs": str(subject.noise.dtype).removeprefix("torch."),
            "parameters": parameter_totals(subject.policy),
            "groups": parameter_dtypes(subject.policy),  # after the fast path, as timed
        },
        fast_path,
        latency,
        first_chunk=first_chunk,
        jump_to_teacher_pass_ratio=jump_ratio,
        jump_to_teacher_marginal_ratio=marginal_ratio,
        throughput=throughput,
        paper_a800={**paper, "end_to_end_speedup": paper["teacher_10_ms"] / paper["snapflow_1_ms"]} if paper else None,
        profile=profiled,
    )


__all__ = [
    "TEACHER_MODES",
    "profile_one_step",
    "measure_throughput",
    "one_step_actions",
    "time_first_chunk",
    "run_bench",
]
