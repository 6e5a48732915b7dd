"""``snapflow bench``: batch-1 latency of one policy at NFE 10, 5, 2 and 1, with the fast path and a profile
(the report it makes: :mod:`snapflow.benchmark.report`).

One step is what deployment runs: the prefix encoded once per chunk, then one pass of the action expert. Optionally
the policy runs a registered fast path (:mod:`snapflow.inference.fast_paths`: ``compile``, ``compile-reduce-overhead``
capturing CUDA graphs on a GPU, ...) and in bfloat16 / float16. The profile of the one-step path shows where its time
goes.
"""

from __future__ import annotations

import contextlib
import functools
import time
from collections.abc import Iterator

import torch

from snapflow.adapters.lerobot_types import LEROBOT_POLICY_TYPES
from snapflow.benchmark.latency import Timing, measure_latency, time_round_robin
from snapflow.benchmark.report import BenchReport, OneStepProfile, Throughput
from snapflow.benchmark.subjects import BenchSubject, parameter_dtypes
from snapflow.flow.modes import SamplingMode
from snapflow.flow.solver import sample_actions
from snapflow.inference.fast_paths import apply_fast_path
from snapflow.protocol import map_tensors
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


@contextlib.contextmanager
def _tf32() -> Iterator[None]:
    """Float32 matrix products in TF32 (on GPUs that have it; LeRobot leaves it off) while active."""
    before = (
        torch.backends.cuda.matmul.allow_tf32,
        torch.backends.cudnn.allow_tf32,
        torch.get_float32_matmul_precision(),
    )
    torch.backends.cuda.matmul.allow_tf32 = torch.backends.cudnn.allow_tf32 = True
    torch.set_float32_matmul_precision("high")
    try:
        yield
    finally:
        torch.backends.cuda.matmul.allow_tf32, torch.backends.cudnn.allow_tf32 = before[:2]
        torch.set_float32_matmul_precision(before[2])


@torch.inference_mode()
def one_step_actions(subject: BenchSubject) -> torch.Tensor:
    """The subject's one-step actions on its own inputs, in float32: what a precision option is measured by."""
    return sample_actions(subject.policy, subject.observation, subject.noise, subject.one_step).float()


def vision_in_bfloat16(subject: BenchSubject) -> float:
    """Run a pi0 / pi0.5 subject's vision tower in bfloat16 (LeRobot keeps it in float32) and return how far that
    moves its one-step actions on its inputs."""
    if not callable(getattr(subject.policy, "run_vision_in", None)):
        raise ValueError(
            "--vision-dtype applies to LeRobot's pi0 and pi0.5, whose vision tower LeRobot keeps in float32"
        )
    exact = one_step_actions(subject)
    subject.policy.run_vision_in(torch.bfloat16)
    subject.details["dtypes"] = parameter_dtypes(subject.policy.policy)
    return (one_step_actions(subject) - exact).abs().max().item()


def run_bench(
    subject: BenchSubject,
    warmup: int = 10,
    repeats: int = 50,
    fast_path: str | None = None,
    profile: bool = True,
    modes: tuple[SamplingMode, ...] | None = None,
    batch_sizes: tuple[int, ...] = (),
    tf32: bool = False,
) -> BenchReport:
    """Time ``subject`` at batch 1 at every mode (default: the teacher's 10, 5, 2 steps and the subject's one-step
    mode; the first is the reference of the speedups), the throughput of the first and last mode at
    ``batch_sizes``, and, optionally, profile its one-step mode, with the policy in fast path ``fast_path`` (a
    registered name, :func:`snapflow.inference.apply_fast_path`) where one is given."""
    modes = modes or subject.only_modes or (*TEACHER_MODES, subject.one_step)
    exact = one_step_actions(subject) if tf32 else None
    with _tf32() if tf32 else contextlib.nullcontext():
        # what TF32 costs in accuracy, measured on the subject's inputs before it is timed
        tf32_difference = (one_step_actions(subject) - exact).abs().max().item() if exact is not None else None
        if fast_path:
            apply_fast_path(subject.policy, fast_path)
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
    declared = LEROBOT_POLICY_TYPES.get(subject.details.get("policy_type", ""))
    paper = declared.paper_latency if declared else None  # the paper's A800 figures, end-to-end ms, batch 1
    return BenchReport(
        subject.name,
        subject.details,
        machine(),
        str(subject.noise.dtype).removeprefix("torch."),
        fast_path,
        latency,
        tf32_difference=tf32_difference,
        jump_to_teacher_pass_ratio=jump_ratio,
        throughput=throughput,
        paper_a800={**paper, "end_to_end_speedup": paper["teacher_10_ms"] / paper["snapflow_1_ms"]} if paper else None,
        profile=profiled,
    )


__all__ = [
    "TEACHER_MODES",
    "profile_one_step",
    "measure_throughput",
    "one_step_actions",
    "vision_in_bfloat16",
    "run_bench",
]
