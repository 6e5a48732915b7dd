"""Evaluation reports: ``report.json`` for machines, ``report.md`` for people, PNG plots for both."""

from __future__ import annotations

from pathlib import Path

from snapflow.envs.factory import make_benchmark
from snapflow.evaluation.path_modes import PATH_MODES_NOTE, markdown_path_modes, mode_coverage
from snapflow.evaluation.results import EvaluationReport
from snapflow.evaluation.switches import SWITCHES_NOTE, markdown_switches
from snapflow.flow.modes import SamplingMode
from snapflow.reporting.figures import pyplot, save_figure
from snapflow.reporting.files import write_json, write_text
from snapflow.reporting.machine import machine_description, versions
from snapflow.reporting.tables import markdown_table


def _rtc_sentence(rtc: dict | None) -> str:
    """How chunks continued each other under an inference delay, where they did."""
    if not rtc:
        return ""
    horizon = rtc["execution_horizon"] or "the previous chunk's end"
    return (
        f" Inference delay of {rtc['delay']} action(s): each chunk after the first planned while the previous one's last "
        f"{rtc['delay']} ran, continuing it by real-time chunking '{rtc['kind']}' ({rtc['schedule']} prefix weights to "
        f"{horizon}); chunk switches at steps n_act, 2 n_act, ..."
    )


def _intervals_markdown(report: EvaluationReport) -> str:
    """Each row's mean with its 95% Wilson interval, and its paired difference from the first row."""
    intervals = report.intervals()
    reference = next(iter(report.rows))
    rows = [
        [
            label,
            f"{entry['success']:.1f}% [{entry['low']:.1f}, {entry['high']:.1f}]",
            f"{entry['difference']:+.1f} [{entry['difference_low']:+.1f}, {entry['difference_high']:+.1f}]"
            if "difference" in entry
            else "reference",
        ]
        for label, entry in intervals.items()
    ]
    episodes = report.rows[reference].success["mean"].episodes
    return (
        markdown_table(["row", "mean success [95% Wilson]", f"points from {reference} [95% paired bootstrap]"], rows)
        + f"\n\nIntervals: Wilson over the {episodes} pooled episodes of a row; the difference is paired over the "
        f"{len(report.tasks)} tasks (every row runs the same evaluation variations), resampled 10,000 times."
    )


def _path_and_switch_sections(report: EvaluationReport) -> list[str]:
    """Where measured: which way each row's executed paths went, and how smoothly its chunks joined."""
    sections: list[str] = []
    benchmark = make_benchmark(report.env)
    counted = {label: row.path_modes for label, row in report.rows.items() if row.path_modes is not None}
    if counted:
        coverage = {
            label: mode_coverage([counts], report.tasks, benchmark.path_modes, benchmark.path_mode_weights)
            for label, counts in counted.items()
        }
        sections += ["## Where the executed paths went", markdown_path_modes(coverage), PATH_MODES_NOTE]
    switches = {label: row.switches for label, row in report.rows.items() if row.switches is not None}
    if switches:
        sections += ["## How smoothly the chunks joined", markdown_switches(switches), SWITCHES_NOTE]
    return sections


def markdown_report(report: EvaluationReport) -> str:
    labels = list(report.rows)
    success_rows = []
    for task in [*report.tasks, "mean"]:
        cells = [
            f"{100 * entry.success_rate:.1f}% ({entry.successes}/{entry.episodes})"
            for entry in (report.rows[label].success[task] for label in labels)
        ]
        success_rows.append(["**mean**" if task == "mean" else task, *cells])
    sections = [
        f"# SnapFlow on {make_benchmark(report.env).describe(report.tasks)}",
        f"{len(report.tasks)} task(s), {report.episodes_per_task} episodes per task on evaluation variations no demonstration saw "
        f"({report.first_variation} to {report.first_variation + report.episodes_per_task - 1} of each task), "
        f"{report.n_act} actions executed per predicted chunk."
        + (f" Episodes cut at {report.max_episode_steps} steps." if report.max_episode_steps else "")
        + _rtc_sentence(report.rtc),
        "\n".join(
            f"- **{label}**: {SamplingMode.parse(row.mode).description} (`{row.policy}`)."
            for label, row in report.rows.items()
        ),
        "## Closed-loop success",
        markdown_table(["task", *labels], success_rows),
        _intervals_markdown(report),
    ]
    sections += _path_and_switch_sections(report)
    offline = {label: row.offline for label, row in report.rows.items() if row.offline is not None}
    if offline:
        samples = next(iter(offline.values())).samples
        sections += [
            f"## Offline action error ({samples} held-out demonstration chunks, normalised actions)",
            markdown_table(
                ["sampler", "MSE", "median", "std", "P90", "P95", "cosine"],
                [
                    [
                        label,
                        *(f"{value:.4f}" for value in (m.mse, m.mse_median, m.mse_std, m.mse_p90, m.mse_p95, m.cosine)),
                    ]
                    for label, m in offline.items()
                ],
            ),
        ]
    if report.latency:
        sections += [
            f"## Latency per chunk, batch 1 ({report.machine or machine_description()}; medians after warm-up)",
            markdown_table(
                [
                    "sampler",
                    "NFE",
                    "prefix ms",
                    "denoising ms",
                    "end-to-end ms",
                    "denoising share",
                    "denoising speedup",
                    "end-to-end speedup",
                ],
                [
                    [
                        label,
                        m.nfe,
                        f"{m.prefix.median_ms:.2f}",
                        f"{m.denoising.median_ms:.2f}",
                        f"{m.end_to_end.median_ms:.2f}",
                        f"{100 * m.denoising_share:.0f}%",
                        f"{m.denoising_speedup:.1f}x",
                        f"{m.end_to_end_speedup:.2f}x",
                    ]
                    for label, m in report.latency.items()
                ],
            ),
        ]
    if report.timings:
        sections += [
            "## Wall time",
            markdown_table(
                ["stage", "seconds"],
                [[stage.removesuffix("_s"), f"{seconds:.0f}"] for stage, seconds in report.timings.items()],
            ),
        ]
    return "\n\n".join(sections) + "\n"


def plot_success(report: EvaluationReport, path: Path) -> None:
    plt = pyplot()
    tasks = [*report.tasks, "mean"]
    labels = list(report.rows)
    width = 0.8 / len(labels)
    figure, axis = plt.subplots(figsize=(max(6, 1.1 * len(tasks)), 4))
    for column, label in enumerate(labels):
        rates = [100 * report.rows[label].success[task].success_rate for task in tasks]
        axis.bar([i + column * width for i in range(len(tasks))], rates, width, label=label)
    axis.set_xticks([i + width * (len(labels) - 1) / 2 for i in range(len(tasks))])
    axis.set_xticklabels([task.removesuffix("-v3") for task in tasks], rotation=35, ha="right", fontsize=8)
    axis.set_ylabel(f"success % ({report.episodes_per_task} episodes per task)")
    axis.set_ylim(0, 118)  # headroom so the one-row legend sits above the 100% bars
    axis.legend(fontsize=8, loc="upper center", ncol=len(labels))
    axis.set_title(f"{make_benchmark(report.env).describe(report.tasks)} closed-loop success")
    figure.tight_layout()
    save_figure(figure, path)


def plot_latency(report: EvaluationReport, path: Path) -> None:
    plt = pyplot()
    labels = list(report.latency)
    prefix = [report.latency[label].prefix.median_ms for label in labels]
    denoise = [report.latency[label].denoising.median_ms for label in labels]
    figure, axis = plt.subplots(figsize=(6, 3.5))
    axis.bar(labels, prefix, label="prefix (encode)")
    axis.bar(labels, denoise, bottom=prefix, label="denoising")
    axis.set_ylabel("ms per chunk (median, batch 1)")
    axis.legend()
    axis.set_title(report.machine or machine_description(), fontsize=9)
    figure.tight_layout()
    save_figure(figure, path)


def write_report(report: EvaluationReport, directory: str | Path) -> None:
    """``report.json``, ``report.md``, ``success.png`` and (with latency) ``latency.png`` in ``directory``."""
    directory = Path(directory)
    report.machine = report.machine or machine_description()
    report.versions = report.versions or versions()
    write_json(directory / "report.json", report.to_dict())
    write_text(directory / "report.md", markdown_report(report))
    plot_success(report, directory / "success.png")
    if report.latency:
        plot_latency(report, directory / "latency.png")


__all__ = ["write_report", "markdown_report", "plot_success", "plot_latency"]
