"""``snapflow bench``: batch-1 latency of one policy at NFE 10, 5, 2 and 1, with the fast path and a profile.

The fast path is what deployment runs: the prefix encoded once per chunk, then one pass of the action expert.
Optionally that pass is compiled (:func:`snapflow.inference.compile_policy`; ``reduce-overhead`` captures a CUDA graph on a GPU)
and the policy runs in bfloat16 / float16. The profile of the one-step path shows where its time goes.
"""

from __future__ import annotations

import contextlib
import functools
import time
from collections.abc import Iterator
from dataclasses import asdict
from pathlib import Path
from typing import Any

import torch

from snapflow.benchmark.latency import measure_latency, time_round_robin
from snapflow.benchmark.subjects import BenchSubject, parameter_dtypes
from snapflow.flow.modes import SamplingMode
from snapflow.flow.solver import sample_actions
from snapflow.inference.compile import compile_policy
from snapflow.protocol import map_tensors
from snapflow.reporting.figures import pyplot, save_figure
from snapflow.reporting.files import write_json, write_text
from snapflow.reporting.machine import machine
from snapflow.reporting.tables import markdown_table

# the teacher's step counts timed before the subject's one-step mode
TEACHER_MODES = (SamplingMode(10, jump=False), SamplingMode(5, jump=False), SamplingMode(2, jump=False))
# the paper's A800 figures (end-to-end ms per chunk, batch 1), for the LeRobot architectures
PAPER_A800 = {
    "pi05": {"teacher_10_ms": 274.0, "snapflow_1_ms": 83.0, "denoising_share_10": 241.0 / 274.0, "per_step_ms": 23.0},
    "smolvla": {"teacher_10_ms": 178.0, "snapflow_1_ms": 50.0},
}


@torch.inference_mode()
def profile_one_step(subject: BenchSubject, calls: int = 20) -> tuple[str, dict[str, float]]:
    """torch.profiler table of ``calls`` one-step generations, and how the wall time splits: the operators'
    own time against everything else (Python, dispatch, framework)."""
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
    return table, {
        "calls": calls,
        "wall_ms_per_call": wall_ms,
        "aten_self_cpu_ms_per_call": operator_ms,
        "outside_aten_share": max(0.0, 1 - operator_ms / wall_ms),
    }


def _repeat_first_row(tensor: torch.Tensor, size: int) -> torch.Tensor:
    return tensor[:1].expand(size, *tensor.shape[1:]).clone()


@torch.inference_mode()
def measure_throughput(
    subject: BenchSubject, modes: tuple[SamplingMode, ...], batch_sizes: tuple[int, ...], warmup: int, repeats: int
) -> dict[str, dict[str, Any]]:
    """End-to-end ms per batch and chunks per second of each mode at each batch size (the batch-1 observation
    repeated), timed round-robin within a batch size."""
    results: dict[str, dict[str, Any]] = {}
    for size in batch_sizes:
        observation = map_tensors(subject.observation, functools.partial(_repeat_first_row, size=size))
        noise = _repeat_first_row(subject.noise, size)
        functions = {
            mode.name: functools.partial(sample_actions, subject.policy, observation, noise, mode) for mode in modes
        }
        timed = time_round_robin(functions, noise.device, warmup, repeats)
        results[str(size)] = {
            name: {"end_to_end": asdict(timing), "chunks_per_s": size * 1e3 / timing.median_ms}
            for name, timing in timed.items()
        }
    return results


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
    compile_mode: str | None = None,
    profile: bool = True,
    modes: tuple[SamplingMode, ...] | None = None,
    batch_sizes: tuple[int, ...] = (),
    tf32: bool = False,
) -> dict[str, Any]:
    """Time ``subject`` at batch 1 at every mode (default: the teacher's 10, 5, 2 steps and the subject's one-step
    mode; the first is the reference of the speedups), the throughput of the first and last mode at
    ``batch_sizes``, and, optionally, profile its one-step mode. ``compile_mode`` runs the fast path
    (:func:`snapflow.inference.compile_policy`)."""
    modes = modes or subject.only_modes or (*TEACHER_MODES, subject.one_step)
    exact = one_step_actions(subject) if tf32 else None
    with _tf32() if tf32 else contextlib.nullcontext():
        # what TF32 costs in accuracy, measured on the subject's inputs before it is timed
        tf32_difference = (one_step_actions(subject) - exact).abs().max().item() if exact is not None else None
        if compile_mode:
            compile_policy(subject.policy, compile_mode)
        latency = measure_latency(subject.policy, subject.observation, subject.noise, list(modes), warmup, repeats)
        throughput = (
            measure_throughput(
                subject, tuple(dict.fromkeys((modes[0], modes[-1]))), batch_sizes, min(warmup, 3), max(3, repeats // 5)
            )
            if batch_sizes
            else None
        )
        profiled = profile_one_step(subject) if profile else None
    report: dict[str, Any] = {
        "subject": subject.name,
        "details": subject.details,
        "machine": machine(),
        "dtype": str(subject.noise.dtype).removeprefix("torch."),
        "compile": compile_mode,
        "latency": latency.to_dict(),
    }
    if tf32_difference is not None:
        report["tf32"] = {"max_abs_action_difference": tf32_difference}
    teacher, one_step = latency.modes[modes[0].name], latency.modes[modes[-1].name]
    if modes[-1].jump and not modes[0].jump:
        # what one jump costs against one teacher step: phi_s's s path should add nothing measurable
        report["jump_to_teacher_pass_ratio"] = one_step.per_pass_ms / teacher.per_pass_ms
    if throughput is not None:
        report["throughput"] = throughput
    paper = PAPER_A800.get(subject.details.get("policy_type", ""))
    if paper:
        report["paper_a800"] = {**paper, "end_to_end_speedup": paper["teacher_10_ms"] / paper["snapflow_1_ms"]}
    if profiled is not None:
        report["profile_table"], report["profile_one_step"] = profiled
    return report


def _precision(report: dict[str, Any]) -> str:
    """The precision the weights actually run in: parameter counts per dtype over every module group (a single
    requested dtype hides the layers a policy keeps in float32)."""
    groups = report["details"].get("dtypes")
    if not groups:
        return f"inputs {report['dtype']}"
    totals: dict[str, int] = {}
    for counts in groups.values():
        for name, count in counts.items():
            totals[name] = totals.get(name, 0) + count
    return "weights " + " + ".join(f"{count / 1e6:.1f}M {name}" for name, count in sorted(totals.items()))


def markdown_bench(report: dict[str, Any]) -> str:
    latency, host = report["latency"], report["machine"]
    device = host["gpu"] or f"{host['cpu']} ({host['threads']} threads)"
    lines = [
        f"# Latency: {report['subject']}",
        "",
        f"Batch 1 on {device}, {_precision(report)}, torch {host['torch']}, compile: {report['compile'] or 'off'}; medians (P90) of "
        f"{latency['repeats']} round-robin repeats after {latency['warmup']} warm-up calls of each.",
        "",
        f"Prefix (VLM) encoding: {latency['prefix']['median_ms']:.2f} ms (P90 {latency['prefix']['p90_ms']:.2f}).",
        "",
        markdown_table(
            [
                "mode",
                "NFE",
                "denoising ms",
                "per pass ms",
                "end-to-end ms",
                "denoising share",
                "denoising speedup",
                "end-to-end speedup",
            ],
            [
                [
                    name,
                    entry["nfe"],
                    f"{entry['denoising']['median_ms']:.2f} ({entry['denoising']['p90_ms']:.2f})",
                    f"{entry['per_pass_ms']:.2f}",
                    f"{entry['end_to_end']['median_ms']:.2f} ({entry['end_to_end']['p90_ms']:.2f})",
                    f"{entry['denoising_share']:.0%}",
                    f"{entry['denoising_speedup']:.2f}x",
                    f"{entry['end_to_end_speedup']:.2f}x",
                ]
                for name, entry in latency["modes"].items()
            ],
        ),
    ]
    if len(report["details"].get("dtypes", {})) > 1:
        lines += [
            "",
            "Parameters by module group and dtype:",
            "",
            markdown_table(
                ["module group", "parameters by dtype"],
                [
                    [group, ", ".join(f"{count:,} {name}" for name, count in counts.items())]
                    for group, counts in report["details"]["dtypes"].items()
                ],
            ),
        ]
    if "distill_step" in report:
        step = report["distill_step"]
        lines += [
            "",
            f"One distillation step (the paper's objective and target, backward, AdamW on the expert; medians of "
            f"{step['repeats']} after {step['warmup']} warm-up steps; peak memory: {step['peak_memory']}):",
            "",
            markdown_table(
                ["batch", "ms per step", "P90", "peak memory GiB"],
                [
                    [
                        row["batch_size"],
                        f"{row['step_ms_median']:.1f}",
                        f"{row['step_ms_p90']:.1f}",
                        f"{row['peak_memory_gib']:.2f}",
                    ]
                    for row in step["rows"]
                ],
            ),
        ]
    if "vision_bfloat16" in report:
        lines += [
            "",
            f"Vision tower in bfloat16: the one-step actions move by at most "
            f"{report['vision_bfloat16']['max_abs_action_difference']:.2e} (normalised units) on these inputs.",
        ]
    if "tf32" in report:
        lines += [
            "",
            f"TF32 on: the one-step actions move by at most {report['tf32']['max_abs_action_difference']:.2e} "
            "(normalised units) on these inputs.",
        ]
    if "jump_to_teacher_pass_ratio" in report:
        lines += [
            "",
            f"One jump costs {report['jump_to_teacher_pass_ratio']:.2f}x one teacher step (per-pass medians above).",
        ]
    if "throughput" in report:
        sizes = list(report["throughput"])
        names = list(report["throughput"][sizes[0]])
        lines += [
            "",
            f"Throughput (end-to-end; medians of {report['throughput'][sizes[0]][names[0]]['end_to_end']['repeats']} "
            "round-robin repeats per batch size):",
            "",
            markdown_table(
                ["batch", *(f"{name} ms" for name in names), *(f"{name} chunks/s" for name in names)],
                [
                    [
                        size,
                        *(f"{report['throughput'][size][name]['end_to_end']['median_ms']:.2f}" for name in names),
                        *(f"{report['throughput'][size][name]['chunks_per_s']:.1f}" for name in names),
                    ]
                    for size in sizes
                ],
            ),
        ]
    if "paper_a800" in report:
        paper = report["paper_a800"]
        lines += [
            "",
            f"The paper on an A800: {paper['teacher_10_ms']:.0f} ms (10-step teacher) -> {paper['snapflow_1_ms']:.0f} ms "
            f"(SnapFlow 1-step) end-to-end, {paper['end_to_end_speedup']:.1f}x.",
        ]
    if "profile_one_step" in report:
        summary = report["profile_one_step"]
        lines += [
            "",
            f"Profile of the 1-NFE path ({summary['calls']} calls, `profile.txt`): {summary['wall_ms_per_call']:.2f} ms a call "
            f"under the profiler, of which operators' own time {summary['aten_self_cpu_ms_per_call']:.2f} ms; "
            f"{summary['outside_aten_share']:.0%} outside them (Python, dispatch, profiler).",
        ]
    return "\n".join(lines)


def plot_bench(report: dict[str, Any], path: Path) -> None:
    plt = pyplot()
    latency = report["latency"]
    labels = list(latency["modes"])
    prefix = [latency["prefix"]["median_ms"]] * len(labels)
    denoise = [latency["modes"][label]["denoising"]["median_ms"] for label in labels]
    other = [
        max(0.0, latency["modes"][label]["end_to_end"]["median_ms"] - p - d)
        for label, p, d in zip(labels, prefix, denoise, strict=True)
    ]
    figure, axis = plt.subplots(figsize=(6.5, 3.8))
    axis.bar(labels, prefix, label="prefix (VLM)")
    axis.bar(labels, denoise, bottom=prefix, label="denoising")
    axis.bar(
        labels, other, bottom=[p + d for p, d in zip(prefix, denoise, strict=True)], label="other", color="lightgray"
    )
    for index, label in enumerate(labels):
        axis.annotate(
            f"{latency['modes'][label]['end_to_end_speedup']:.1f}x",
            (index, prefix[index] + denoise[index] + other[index]),
            ha="center",
            va="bottom",
            fontsize=8,
        )
    axis.set_ylim(
        top=1.12 * max(p + d + o for p, d, o in zip(prefix, denoise, other, strict=True))
    )  # room for the labels
    axis.set_ylabel("ms per chunk (median, batch 1)")
    axis.legend(fontsize=8)
    host = report["machine"]
    axis.set_title(f"{report['subject']} on {host['gpu'] or host['cpu']}", fontsize=8)
    figure.tight_layout()
    save_figure(figure, path)


def write_bench(report: dict[str, Any], directory: str | Path) -> Path:
    """``bench.json``, ``bench.md``, ``latency.png`` and (when profiled) ``profile.txt``."""
    directory = Path(directory)
    write_json(directory / "bench.json", {key: value for key, value in report.items() if key != "profile_table"})
    write_text(directory / "bench.md", markdown_bench(report) + "\n")
    plot_bench(report, directory / "latency.png")
    if "profile_table" in report:
        write_text(directory / "profile.txt", report["profile_table"] + "\n")
    return directory


__all__ = [
    "TEACHER_MODES",
    "PAPER_A800",
    "profile_one_step",
    "measure_throughput",
    "one_step_actions",
    "vision_in_bfloat16",
    "run_bench",
    "markdown_bench",
    "plot_bench",
    "write_bench",
]
