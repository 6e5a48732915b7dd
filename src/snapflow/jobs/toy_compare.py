"""Several distillation settings on the toy mixture, over seeds: which one-step target gets closest to the data.

Each (setting, seed) is one :class:`ToyJob` on :mod:`snapflow.jobs.runner`, cached as
``runs/<option>/seed-<seed>.json`` (its record: the config, the energy distances and the seconds per step), so an
interrupted comparison resumes and a run made with other settings runs again. The summary gives, per setting, the
1-NFE energy distance (mean, sample std, per seed), its ratio to the first setting's and to the 10-step teacher's,
the no-grad passes its target costs per one-step row, and the seconds per step.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from snapflow.errors import InvalidInputError
from snapflow.flow.modes import NAIVE_1, SNAPFLOW_1, TEACHER_10
from snapflow.jobs.runner import Job, read_record, run_jobs
from snapflow.jobs.toy import run_toy_experiment
from snapflow.jobs.toy_config import ToyConfig
from snapflow.reporting.figures import pyplot, save_figure
from snapflow.reporting.files import write_json, write_text
from snapflow.reporting.statistics import mean_std
from snapflow.reporting.tables import markdown_table
from snapflow.training.recipes import TargetOption


@dataclass(frozen=True)
class ToyJob(Job):
    """One toy experiment; its record at ``path`` holds the energy distances and seconds per distillation step."""

    kind: ClassVar[str] = "toy"
    name: str  # the target option's
    config: ToyConfig
    path: Path

    def settings(self) -> dict[str, Any]:
        return self.config.record()

    @property
    def record_path(self) -> Path:
        return self.path

    def run(self) -> dict[str, Any]:
        result = run_toy_experiment(self.config, progress=False)
        return {"energy_distance": result.distances, "distill_step_s": result.distill_step_s}

    def describe(self) -> str:
        return f"{self.name} seed {self.config.seed}"


def compare_targets(
    options: list[TargetOption],
    seeds: list[int],
    base: ToyConfig,
    output_dir: str | Path,
    workers: int = 1,
    progress: bool = True,
    threads: int | None = None,
) -> dict[str, Any]:
    """Run what is not done (on ``workers`` processes of ``threads`` torch threads, by default cores / workers),
    then write ``comparison.json``, ``comparison.md`` and ``comparison.png``."""
    if not options or not seeds:
        raise InvalidInputError("compare at least one target option on at least one seed")
    output_dir = Path(output_dir)
    jobs = {
        (option, seed): ToyJob(
            option.name,
            replace(base, seed=seed, distill=option.settings(base.distill)),
            output_dir / "runs" / option.name / f"seed-{seed}.json",
        )
        for option in options
        for seed in seeds
    }
    run_jobs(jobs.values(), workers, progress, description="toy runs", threads=threads)
    runs = {key: read_record(job) for key, job in jobs.items()}

    def per_seed(option: TargetOption, name: str) -> list[float]:
        return [runs[(option, seed)]["energy_distance"][name] for seed in seeds]

    teacher, reference = per_seed(options[0], TEACHER_10.name), per_seed(options[0], SNAPFLOW_1.name)
    rows = []
    for option in options:
        distances = per_seed(option, SNAPFLOW_1.name)
        mean, std = mean_std(distances)
        step_ms = [1000 * runs[(option, seed)]["distill_step_s"] for seed in seeds]
        rows.append(
            {
                "option": option.name,
                "label": option.label,
                "target": option.target,
                "target_steps": option.steps if isinstance(option.steps, int) else list(option.steps),
                "distance_mean": mean,
                "distance_std": std,
                "distance_per_seed": distances,
                "ratio_to_first_mean": float(np.mean(np.divide(distances, reference))),
                "ratio_to_teacher_mean": float(np.mean(np.divide(distances, teacher))),
                "teacher_passes_per_row": option.teacher_passes,
                "step_ms_median": float(np.median(step_ms)),
                "step_ms_per_seed": step_ms,
            }
        )
    summary: dict[str, Any] = {
        "config": {**base.record(), "seed": None, "target": None, "target_steps": None},
        "seeds": seeds,
    }
    for name in (TEACHER_10.name, NAIVE_1.name):  # one teacher per seed, whatever the target
        values = per_seed(options[0], name)
        mean, std = mean_std(values)
        summary[name] = {"mean": mean, "std": std, "per_seed": values}
    summary["rows"] = rows
    write_json(output_dir / "comparison.json", summary)
    write_text(output_dir / "comparison.md", markdown_comparison(summary) + "\n")
    plot_comparison(summary, output_dir / "comparison.png")
    return summary


def markdown_comparison(summary: dict[str, Any]) -> str:
    """The comparison's caption (settings, the teacher's and the naive step's distances) and one row per target."""
    config, rows = summary["config"], summary["rows"]
    teacher, naive = summary[TEACHER_10.name], summary[NAIVE_1.name]
    caption = (
        f"Toy conditional mixture ({config['num_modes']} modes), seeds {', '.join(map(str, summary['seeds']))}; "
        f"{config['distill_steps']} distillation steps, alpha {config['alpha']}, lambda {config['consistency_weight']}, "
        f"batch {config['batch_size']}; energy distance of {config['eval_contexts']} contexts x "
        f"{config['samples_per_context']} samples to exact samples (lower is better). "
        f"10-step teacher {teacher['mean']:.3f} ± {teacher['std']:.3f}, naive 1-NFE {naive['mean']:.3f} ± {naive['std']:.3f}."
    )
    header = [
        "1-NFE target",
        "energy distance (mean ± std)",
        "per seed",
        f"/ {rows[0]['label']}",
        "/ teacher 10-NFE",
        "no-grad passes per row",
        "ms per step (median)",
    ]
    cells = [
        [
            row["label"],
            f"{row['distance_mean']:.3f} ± {row['distance_std']:.3f}",
            " / ".join(f"{value:.3f}" for value in row["distance_per_seed"]),
            f"{row['ratio_to_first_mean']:.2f}",
            f"{row['ratio_to_teacher_mean']:.2f}",
            f"{row['teacher_passes_per_row']:.3g} + 1",
            f"{row['step_ms_median']:.1f}",
        ]
        for row in rows
    ]
    return f"{caption}\n\n{markdown_table(header, cells)}"


def plot_comparison(summary: dict[str, Any], path: Path) -> None:
    """Bars: 1-NFE distance per target (mean ± std over seeds), with the teacher's and the naive step's levels."""
    plt = pyplot()
    rows = summary["rows"]
    figure, axis = plt.subplots(figsize=(6.4, 3.8))
    positions = np.arange(len(rows))
    means, stds = [row["distance_mean"] for row in rows], [row["distance_std"] for row in rows]
    axis.bar(positions, means, yerr=stds, capsize=4, color="#4c72b0")
    for name, style in ((TEACHER_10.name, "--"), (NAIVE_1.name, ":")):
        axis.axhline(
            summary[name]["mean"], color="black", linestyle=style, label=f"{name} ({summary[name]['mean']:.3f})"
        )
    axis.set_xticks(positions, [row["label"] for row in rows], rotation=20, ha="right")
    axis.set_ylabel("1-NFE energy distance to the data")
    axis.set_title(f"One-step targets on the toy mixture ({len(summary['seeds'])} seeds)", fontsize=9)
    axis.legend(fontsize=8)
    axis.grid(alpha=0.3, axis="y")
    figure.tight_layout()
    save_figure(figure, path, dpi=120)


__all__ = ["ToyJob", "compare_targets", "markdown_comparison", "plot_comparison"]
