"""The report of ``snapflow bench``: what was measured of one subject (``bench.json``), its Markdown (``bench.md``,
one function a section), its plot (``latency.png``) and the profiler's table (``profile.txt``)."""

from __future__ import annotations

from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from snapflow.benchmark.latency import LatencyReport, Timing
from snapflow.reporting.figures import pyplot, save_figure
from snapflow.reporting.files import write_json, write_text
from snapflow.reporting.tables import markdown_table


@dataclass(frozen=True)
class OneStepProfile:
    """Where the one-step path's time goes: torch.profiler's table of ``calls`` generations, and how the wall time
    splits between the operators' own time and everything else (Python, dispatch, framework)."""

    table: str
    calls: int
    wall_ms_per_call: float
    aten_self_cpu_ms_per_call: float
    outside_aten_share: float

    def to_dict(self) -> dict[str, Any]:
        """The summary ``bench.json`` keeps (the table goes to ``profile.txt``)."""
        return {key: value for key, value in asdict(self).items() if key != "table"}


@dataclass(frozen=True)
class Throughput:
    """End-to-end timings of some modes at several batch sizes: batch size -> mode name -> timing."""

    timings: dict[int, dict[str, Timing]]

    def chunks_per_s(self, size: int, mode: str) -> float:
        """Chunks generated per second by ``mode`` at batch ``size`` (medians)."""
        return size * 1e3 / self.timings[size][mode].median_ms

    def to_dict(self) -> dict[str, dict[str, Any]]:
        """Per batch size (as a string) and mode, the timing and chunks per second."""
        return {
            str(size): {
                name: {"end_to_end": asdict(timing), "chunks_per_s": self.chunks_per_s(size, name)}
                for name, timing in timed.items()
            }
            for size, timed in self.timings.items()
        }


@dataclass(frozen=True)
class FirstChunk:
    """A fast path's first one-step chunk: its wall time from the fast path's application (compilation and graph
    capture included), how far its actions are from the eager policy's on the same inputs against the fast path's
    stated bound, the graphs torch.compile made for it (one where nothing breaks the chunk's graph; none for a fast
    path that compiles nothing), and how many compiled graphs torch's on-disk cache held (``cache_hits``) or had to
    compile (``cache_misses``), in cache folder ``compile_cache``."""

    seconds: float
    max_abs_action_difference: float
    action_bound: float | None
    graphs: int
    cache_hits: int
    cache_misses: int
    compile_cache: str

    @property
    def start(self) -> str:
        """``cold`` where anything was compiled afresh, ``warm`` where all came from the cache, else ``none``."""
        return "cold" if self.cache_misses else "warm" if self.cache_hits else "none"

    @property
    def within_bound(self) -> bool | None:
        return None if self.action_bound is None else self.max_abs_action_difference <= self.action_bound

    def to_dict(self) -> dict[str, Any]:
        return {**asdict(self), "start": self.start, "within_bound": self.within_bound}


@dataclass
class BenchReport:
    """What ``snapflow bench`` measured of one subject; ``to_dict()`` is ``bench.json``. The sections after
    ``latency`` are None where they were not measured."""

    subject: str
    details: dict[str, Any]  # the subject's (policy type, sizes, ...)
    machine: dict[str, Any]
    dtype: dict[str, Any]  # the dtype asked for, the inputs', the parameters' count per dtype and per module group
    fast_path: str | None  # the registered name of the fast path timed (snapflow.inference.fast_paths), or None
    latency: LatencyReport
    first_chunk: FirstChunk | None = None  # the fast path's first chunk, where one is timed
    jump_to_teacher_pass_ratio: float | None = None  # one jump's denoising time over one teacher step's
    # one jump's marginal cost (end-to-end minus prefix) over one teacher step's (end-to-end minus prefix, over NFE)
    jump_to_teacher_marginal_ratio: float | None = None
    throughput: Throughput | None = None
    paper_a800: dict[str, float] | None = None  # the paper's figures for this policy type
    profile: OneStepProfile | None = None
    distill_step: dict[str, Any] | None = None  # from snapflow.benchmark.training_cost.distillation_step_cost

    def to_dict(self) -> dict[str, Any]:
        """``bench.json``: every section measured (the profiler's table goes to ``profile.txt`` instead)."""
        report: dict[str, Any] = {
            "subject": self.subject,
            "details": self.details,
            "machine": self.machine,
            "dtype": self.dtype,
            "fast_path": self.fast_path,
            "latency": self.latency.to_dict(),
        }
        if self.first_chunk is not None:
            report["first_chunk"] = self.first_chunk.to_dict()
        if self.jump_to_teacher_pass_ratio is not None:
            report["jump_to_teacher_pass_ratio"] = self.jump_to_teacher_pass_ratio
        if self.jump_to_teacher_marginal_ratio is not None:
            report["jump_to_teacher_marginal_ratio"] = self.jump_to_teacher_marginal_ratio
        if self.throughput is not None:
            report["throughput"] = self.throughput.to_dict()
        if self.paper_a800 is not None:
            report["paper_a800"] = self.paper_a800
        if self.profile is not None:
            report["profile_one_step"] = self.profile.to_dict()
        if self.distill_step is not None:
            report["distill_step"] = self.distill_step
        return report


def _precision(report: BenchReport) -> str:
    """The precision the weights actually run in: parameter counts per dtype over every module group (a single
    requested dtype hides the layers a policy keeps in float32)."""
    totals = report.dtype["parameters"]
    asked = f" (asked: {report.dtype['requested']})"
    if not totals:
        return f"inputs {report.dtype['inputs']}{asked}"
    return "weights " + " + ".join(f"{count / 1e6:.1f}M {name}" for name, count in sorted(totals.items())) + asked


# bench.md: one function a section, each None where its section was not measured, in the order they are written


def _latency_markdown(report: BenchReport) -> str:
    """The title, how it was timed, the prefix, and the table of modes."""
    latency, host = report.latency, report.machine
    device = host["gpu"] or f"{host['cpu']} ({host['threads']} threads)"
    header = ["mode", "NFE", "denoising ms", "per pass ms", "end-to-end ms", "marginal per pass ms", "denoising share"]
    header += ["denoising speedup", "end-to-end speedup"]
    rows = [
        [
            name,
            row.nfe,
            f"{row.denoising.median_ms:.2f} ({row.denoising.p90_ms:.2f})",
            f"{row.per_pass_ms:.2f}",
            f"{row.end_to_end.median_ms:.2f} ({row.end_to_end.p90_ms:.2f})",
            f"{latency.marginal_per_pass_ms(name):.2f}",
            f"{row.denoising_share:.0%}",
            f"{row.denoising_speedup:.2f}x",
            f"{row.end_to_end_speedup:.2f}x",
        ]
        for name, row in latency.modes.items()
    ]
    return "\n".join(
        [
            f"# Latency: {report.subject}",
            "",
            f"Batch 1 on {device}, {_precision(report)}, torch {host['torch']}, "
            f"fast path: {report.fast_path or 'off'}; "
            f"medians (P90) of {latency.repeats} round-robin repeats after {latency.warmup} warm-up calls of each.",
            "",
            f"Prefix (VLM) encoding: {latency.prefix.median_ms:.2f} ms (P90 {latency.prefix.p90_ms:.2f}).",
            "",
            markdown_table(header, rows),
        ]
    )


def _dtypes_markdown(report: BenchReport) -> str | None:
    groups = report.dtype.get("groups", {})
    if len(groups) <= 1:
        return None
    rows = [
        [group, ", ".join(f"{count:,} {name}" for name, count in counts.items())] for group, counts in groups.items()
    ]
    return "Parameters by module group and dtype:\n\n" + markdown_table(["module group", "parameters by dtype"], rows)


def _distill_step_markdown(report: BenchReport) -> str | None:
    step = report.distill_step
    if step is None:
        return None
    rows = [
        [
            row["batch_size"],
            f"{row['step_ms_median']:.1f}",
            f"{row['step_ms_p90']:.1f}",
            f"{row['peak_memory_gib']:.2f}",
        ]
        for row in step["rows"]
    ]
    return (
        f"One distillation step (the paper's objective and target, backward, AdamW on the expert; medians of "
        f"{step['repeats']} after {step['warmup']} warm-up steps; peak memory: {step['peak_memory']}):\n\n"
        + markdown_table(["batch", "ms per step", "P90", "peak memory GiB"], rows)
    )


def _first_chunk_markdown(report: BenchReport) -> str | None:
    first = report.first_chunk
    if first is None:
        return None
    bound = (
        ""
        if first.action_bound is None
        else f" (its stated bound {first.action_bound:g}: " + ("within)" if first.within_bound else "EXCEEDED)")
    )
    return (
        f"First chunk on the fast path: {first.seconds:.1f} s from its application, compilation included, "
        f"{first.start} start ({first.graphs} graph(s); {first.cache_hits} read compiled from the cache "
        f"`{first.compile_cache}`, {first.cache_misses} compiled afresh). "
        f"Its one-step actions are within {first.max_abs_action_difference:.2e} (normalised units) of the eager "
        f"policy's on the same inputs{bound}."
    )


def _jump_markdown(report: BenchReport) -> str | None:
    if report.jump_to_teacher_pass_ratio is None:
        return None
    return (
        f"One jump costs {report.jump_to_teacher_pass_ratio:.2f}x one teacher step by the denoising passes alone, "
        f"{report.jump_to_teacher_marginal_ratio:.2f}x by the marginal cost of a pass (end-to-end minus prefix, over "
        "NFE), medians above."
    )


def _throughput_markdown(report: BenchReport) -> str | None:
    if report.throughput is None:
        return None
    timings = report.throughput.timings
    sizes = list(timings)
    names = list(timings[sizes[0]])
    header = ["batch", *(f"{name} ms" for name in names), *(f"{name} chunks/s" for name in names)]
    rows = [
        [
            size,
            *(f"{timings[size][name].median_ms:.2f}" for name in names),
            *(f"{report.throughput.chunks_per_s(size, name):.1f}" for name in names),
        ]
        for size in sizes
    ]
    return (
        f"Throughput (end-to-end; medians of {timings[sizes[0]][names[0]].repeats} round-robin repeats per batch "
        "size):\n\n" + markdown_table(header, rows)
    )


def _paper_markdown(report: BenchReport) -> str | None:
    paper = report.paper_a800
    if paper is None:
        return None
    return (
        f"The paper on an A800: {paper['teacher_10_ms']:.0f} ms (10-step teacher) -> {paper['snapflow_1_ms']:.0f} ms "
        f"(SnapFlow 1-step) end-to-end, {paper['end_to_end_speedup']:.1f}x."
    )


def _profile_markdown(report: BenchReport) -> str | None:
    profile = report.profile
    if profile is None:
        return None
    return (
        f"Profile of the 1-NFE path ({profile.calls} calls, `profile.txt`): {profile.wall_ms_per_call:.2f} ms a call "
        f"under the profiler, of which operators' own time {profile.aten_self_cpu_ms_per_call:.2f} ms; "
        f"{profile.outside_aten_share:.0%} outside them (Python, dispatch, profiler)."
    )


_SECTIONS = (
    _latency_markdown,
    _dtypes_markdown,
    _distill_step_markdown,
    _first_chunk_markdown,
    _jump_markdown,
    _throughput_markdown,
    _paper_markdown,
    _profile_markdown,
)


def markdown_bench(report: BenchReport) -> str:
    """``bench.md``: the latency table, then each other section that was measured."""
    sections = (markdown(report) for markdown in _SECTIONS)
    return "\n\n".join(section for section in sections if section is not None)


def plot_bench(report: BenchReport, path: Path) -> None:
    """Per mode, the end-to-end time stacked as prefix, denoising and the rest, labelled with its speedup."""
    plt = pyplot()
    latency = report.latency
    labels = list(latency.modes)
    prefix = [latency.prefix.median_ms] * len(labels)
    denoise = [latency.modes[label].denoising.median_ms for label in labels]
    other = [
        max(0.0, latency.modes[label].end_to_end.median_ms - p - d)
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
            f"{latency.modes[label].end_to_end_speedup:.1f}x",
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
    host = report.machine
    axis.set_title(f"{report.subject} on {host['gpu'] or host['cpu']}", fontsize=8)
    figure.tight_layout()
    save_figure(figure, path)


def write_bench(report: BenchReport, directory: str | Path) -> Path:
    """``bench.json``, ``bench.md``, ``latency.png`` and (when profiled) ``profile.txt``."""
    directory = Path(directory)
    write_json(directory / "bench.json", report.to_dict())
    write_text(directory / "bench.md", markdown_bench(report) + "\n")
    plot_bench(report, directory / "latency.png")
    if report.profile is not None:
        write_text(directory / "profile.txt", report.profile.table + "\n")
    return directory


__all__ = ["OneStepProfile", "Throughput", "FirstChunk", "BenchReport", "markdown_bench", "plot_bench", "write_bench"]
