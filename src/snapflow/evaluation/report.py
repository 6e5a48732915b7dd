"""Evaluation reports: JSON for machines, Markdown for people, PNG plots for both."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from snapflow.benchmark.latency import machine
from snapflow.io import atomic_write, write_json


def pyplot():
    """matplotlib.pyplot on the file-only Agg backend (no display needed)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def mean_std(values: list[float]) -> tuple[float, float]:
    """Mean and sample standard deviation (0 for a single value) of per-seed results."""
    return float(np.mean(values)), float(np.std(values, ddof=1)) if len(values) > 1 else 0.0


def machine_description() -> str:
    """The machine of :func:`snapflow.benchmark.latency.machine` in a few words, for titles and tables."""
    host = machine()
    return host["gpu"] or f"CPU {host['cpu']}, {host['threads']} threads"


def markdown_report(report: dict[str, Any]) -> str:
    rows = report["rows"]
    labels = list(rows)
    lines = [
        "# SnapFlow on Meta-World MT10",
        "",
        f"{len(report['tasks'])} task(s), {report['episodes_per_task']} episodes per task on evaluation variations no "
        f"demonstration saw, {report['n_act']} actions executed per predicted chunk.",
        "",
        "## Closed-loop success",
        "",
        "| task | " + " | ".join(labels) + " |",
        "|---|" + "---|" * len(labels),
    ]
    for task in [*report["tasks"], "mean"]:
        cells = []
        for label in labels:
            entry = rows[label]["success"][task]
            cells.append(f"{100 * entry['success_rate']:.1f}% ({entry['successes']}/{entry['episodes']})")
        name = "**mean**" if task == "mean" else task
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    offline = {label: row["offline"] for label, row in rows.items() if "offline" in row}
    if offline:
        samples = next(iter(offline.values()))["samples"]
        lines += ["", f"## Offline action error ({samples} held-out demonstration chunks, normalised actions)", "",
                  "| sampler | MSE | median | std | P90 | P95 | cosine |", "|---|---|---|---|---|---|---|"]
        for label, m in offline.items():
            lines.append(f"| {label} | {m['mse']:.4f} | {m['mse_median']:.4f} | {m['mse_std']:.4f} | {m['mse_p90']:.4f} | {m['mse_p95']:.4f} | {m['cosine']:.4f} |")
    if report.get("latency"):
        lines += ["", f"## Latency per chunk, batch 1 ({report.get('machine', machine_description())}; medians after warm-up)", "",
                  "| sampler | NFE | prefix ms | denoising ms | end-to-end ms | denoising share | denoising speedup | end-to-end speedup |",
                  "|---|---|---|---|---|---|---|---|"]
        for label, m in report["latency"].items():
            lines.append(
                f"| {label} | {m['nfe']} | {m['prefix']['median_ms']:.2f} | {m['denoising']['median_ms']:.2f} | "
                f"{m['end_to_end']['median_ms']:.2f} | {100 * m['denoising_share']:.0f}% | {m['denoising_speedup']:.1f}x | {m['end_to_end_speedup']:.2f}x |"
            )
    if report.get("timings"):
        lines += ["", "## Wall time", "", "| stage | seconds |", "|---|---|"]
        lines += [f"| {stage.removesuffix('_s')} | {seconds:.0f} |" for stage, seconds in report["timings"].items()]
    return "\n".join(lines) + "\n"


def plot_success(report: dict[str, Any], path: Path) -> None:
    plt = pyplot()
    tasks = [*report["tasks"], "mean"]
    labels = list(report["rows"])
    width = 0.8 / len(labels)
    figure, axis = plt.subplots(figsize=(max(6, 1.1 * len(tasks)), 4))
    for column, label in enumerate(labels):
        rates = [100 * report["rows"][label]["success"][task]["success_rate"] for task in tasks]
        axis.bar([i + column * width for i in range(len(tasks))], rates, width, label=label)
    axis.set_xticks([i + width * (len(labels) - 1) / 2 for i in range(len(tasks))])
    axis.set_xticklabels([task.removesuffix("-v3") for task in tasks], rotation=35, ha="right", fontsize=8)
    axis.set_ylabel(f"success % ({report['episodes_per_task']} episodes per task)")
    axis.set_ylim(0, 118)  # headroom so the one-row legend sits above the 100% bars
    axis.legend(fontsize=8, loc="upper center", ncol=len(labels))
    axis.set_title("Meta-World closed-loop success")
    figure.tight_layout()
    atomic_write(path, lambda temporary: figure.savefig(temporary, dpi=110, format="png"))
    plt.close(figure)


def plot_latency(report: dict[str, Any], path: Path) -> None:
    plt = pyplot()
    labels = list(report["latency"])
    prefix = [report["latency"][label]["prefix"]["median_ms"] for label in labels]
    denoise = [report["latency"][label]["denoising"]["median_ms"] for label in labels]
    figure, axis = plt.subplots(figsize=(6, 3.5))
    axis.bar(labels, prefix, label="prefix (encode)")
    axis.bar(labels, denoise, bottom=prefix, label="denoising")
    axis.set_ylabel("ms per chunk (median, batch 1)")
    axis.legend()
    axis.set_title(report.get("machine", machine_description()), fontsize=9)
    figure.tight_layout()
    atomic_write(path, lambda temporary: figure.savefig(temporary, dpi=110, format="png"))
    plt.close(figure)


def write_report(report: dict[str, Any], directory: str | Path) -> None:
    """``report.json``, ``report.md``, ``success.png`` and (with latency) ``latency.png`` in ``directory``."""
    directory = Path(directory)
    report.setdefault("machine", machine_description())
    write_json(directory / "report.json", report)
    atomic_write(directory / "report.md", lambda temporary: temporary.write_text(markdown_report(report)))
    plot_success(report, directory / "success.png")
    if report.get("latency"):
        plot_latency(report, directory / "latency.png")


__all__ = ["write_report", "markdown_report", "machine_description", "mean_std"]
