"""Several distillation settings on a toy shape, over seeds: which one-step student gets closest to the data.

A setting is a row option: a SnapFlow target (:class:`~snapflow.training.recipes.TargetOption`), a named recipe
(:class:`~snapflow.jobs.toy_config.RecipeOption`) or the high-noise-biased one step
(:class:`~snapflow.jobs.toy_config.BiasedOneStep`). Each (setting, seed) is one :class:`ToyJob` on
:mod:`snapflow.jobs.runner`, cached as ``runs/<option>/seed-<seed>.json`` (its record: the config, the energy
distances, the seconds per step and each sampler's mode coverage), so an interrupted comparison resumes and a run made
with other settings runs again. The summary gives, per setting, the 1-NFE energy distance (mean, sample std, per
seed), its ratio to the first setting's and to the 10-step teacher's (with a 95% interval over seeds), its mode
coverage error, the no-grad passes its target costs per one-step row, and the seconds per step; with
``step_repeats``, also each setting's step cost relative to the first's, timed round-robin
(:func:`snapflow.jobs.toy_coverage.step_costs`).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, ClassVar, Protocol

import numpy as np

from snapflow.errors import InvalidInputError
from snapflow.flow.modes import NAIVE_1, SNAPFLOW_1, TEACHER_10
from snapflow.flow.time_sampling import UniformTimeSampler
from snapflow.jobs.runner import Job, read_record, run_jobs
from snapflow.jobs.toy import run_toy_experiment
from snapflow.jobs.toy_config import ToyConfig
from snapflow.objective.settings import DistillSettings
from snapflow.reporting.figures import pyplot, save_figure
from snapflow.reporting.files import write_json, write_text
from snapflow.reporting.statistics import mean_std, t_interval_95
from snapflow.reporting.tables import markdown_table


class RowOption(Protocol):
    """A row of the comparison: its name (its runs' folder), label, settings over the base's, and no-grad passes."""

    @property
    def name(self) -> str: ...

    @property
    def label(self) -> str: ...

    @property
    def teacher_passes(self) -> float: ...

    def settings(self, base: DistillSettings | None = None) -> DistillSettings: ...


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
        record = result.to_dict()
        kept = ("energy_distance", "distill_step_s", "coverage_error", "mode_shares", "true_mode_weights")
        return {key: record[key] for key in kept}

    def describe(self) -> str:
        return f"{self.name} seed {self.config.seed}"


def _coverage(runs: list[dict[str, Any]], name: str) -> dict[str, Any]:
    """Sampler ``name``'s coverage error over the seeds' runs (mean, per seed); none where a run predates it."""
    if not all("coverage_error" in run for run in runs):
        return {}
    values = [run["coverage_error"][name] for run in runs]
    return {"coverage_error_mean": float(np.mean(values)), "coverage_error_per_seed": values}


def _row(
    option: RowOption,
    settings: DistillSettings,
    runs: list[dict[str, Any]],
    teacher: list[float],
    reference: list[float],
) -> dict[str, Any]:
    """One row of the summary: the option's 1-NFE distances over seeds, their ratios, coverage and cost."""
    distances = [run["energy_distance"][SNAPFLOW_1.name] for run in runs]
    mean, std = mean_std(distances)
    ratios = np.divide(distances, teacher)
    step_ms = [1000 * run["distill_step_s"] for run in runs]
    row = {
        "option": option.name,
        "label": option.label,
        "target": settings.target,
        "target_steps": settings.target_steps
        if isinstance(settings.target_steps, int)
        else list(settings.target_steps),
        "distance_mean": mean,
        "distance_std": std,
        "distance_per_seed": distances,
        "ratio_to_first_mean": float(np.mean(np.divide(distances, reference))),
        "ratio_to_teacher_mean": float(np.mean(ratios)),
        "teacher_passes_per_row": option.teacher_passes,
        "step_ms_median": float(np.median(step_ms)),
        "step_ms_per_seed": step_ms,
    }
    coverage = _coverage(runs, SNAPFLOW_1.name)
    if coverage:  # a comparison of coverage also names each row's settings and the interval of its ratio
        low, high = t_interval_95(list(ratios))
        samples = getattr(settings.objective(UniformTimeSampler()), "energy_samples", 1)
        row.update(
            coverage,
            ratio_to_teacher_per_seed=ratios.tolist(),
            ratio_to_teacher_interval=[low, high],
            alpha=settings.alpha,
            consistency_weight=settings.consistency_weight,
            student_rows_per_row=samples,
        )
    return row


def compare_targets(
    options: list[RowOption],
    seeds: list[int],
    base: ToyConfig,
    output_dir: str | Path,
    workers: int = 1,
    progress: bool = True,
    threads: int | None = None,
    step_repeats: int = 0,
) -> dict[str, Any]:
    """Run what is not done (on ``workers`` processes of ``threads`` torch threads, by default cores / workers),
    time each option's step round-robin ``step_repeats`` times where asked, then write ``comparison.json``,
    ``comparison.md``, ``comparison.png`` and, where the runs hold mode coverage, ``coverage.png``."""
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
    runs = {option.name: [read_record(jobs[(option, seed)]) for seed in seeds] for option in options}
    first = runs[options[0].name]
    teacher = [run["energy_distance"][TEACHER_10.name] for run in first]
    reference = [run["energy_distance"][SNAPFLOW_1.name] for run in first]
    rows = [
        _row(option, jobs[(option, seeds[0])].config.distill, runs[option.name], teacher, reference)
        for option in options
    ]
    summary: dict[str, Any] = {
        "config": {**base.record(), "seed": None, "target": None, "target_steps": None},
        "seeds": seeds,
    }
    for name in (TEACHER_10.name, NAIVE_1.name):  # one teacher per seed, whatever the target
        values = [run["energy_distance"][name] for run in first]
        mean, std = mean_std(values)
        summary[name] = {"mean": mean, "std": std, "per_seed": values, **_coverage(first, name)}
    if _coverage(first, "data"):
        summary["data"] = _coverage(first, "data")
    summary["rows"] = rows
    if step_repeats:
        from snapflow.jobs.toy_coverage import step_costs

        costs = step_costs({option.name: jobs[(option, seeds[0])].config for option in options}, step_repeats)
        summary["step_cost"] = {"repeats": step_repeats, "clock": "process CPU time", "ms_median": costs}
        for row in rows:
            row["step_cost_ratio"] = costs[row["option"]] / costs[rows[0]["option"]]
    write_json(output_dir / "comparison.json", summary)
    write_text(output_dir / "comparison.md", markdown_comparison(summary) + "\n")
    plot_comparison(summary, output_dir / "comparison.png")
    if "data" in summary:
        from snapflow.jobs.toy_coverage import plot_coverage

        plot_coverage({option.label: runs[option.name][0] for option in options}, output_dir / "coverage.png")
    return summary


def markdown_comparison(summary: dict[str, Any]) -> str:
    """The comparison's caption (settings, the teacher's and the naive step's distances) and one row per target;
    :func:`markdown_coverage`'s table where the runs hold mode coverage."""
    if "data" in summary:
        return markdown_coverage(summary)
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


SHAPE_CAPTIONS = {"mixture": "Toy conditional mixture ({num_modes} modes)", "rings": "Toy conditional two rings"}


def markdown_coverage(summary: dict[str, Any]) -> str:
    """The caption and one row per sampler: the 10-step teacher, the naive step, then each option's one step, with
    its energy distance, ratio to the teacher's (per seed, 95% t interval), coverage error and cost a step."""
    config, rows, seeds = summary["config"], summary["rows"], summary["seeds"]
    costed = "step_cost" in summary
    caption = (
        SHAPE_CAPTIONS[config.get("shape", "mixture")].format(**config)
        + f", seeds {', '.join(map(str, seeds))}; {config['distill_steps']} distillation steps, batch "
        f"{config['batch_size']}; energy distance of {config['eval_contexts']} contexts x "
        f"{config['samples_per_context']} samples to exact samples, and coverage error (per context, the total "
        "variation between the samples' shares of the modes, off every mode one more share, and the true weights; "
        f"exact samples score {summary['data']['coverage_error_mean']:.3f}); lower is better. Cost: no-grad passes + "
        "student rows in the gradient pass, per one-step row"
        + (
            f"; step cost relative to the first row's, timed round-robin ({summary['step_cost']['repeats']} rounds"
            + (f", {summary['step_cost']['clock']}" if "clock" in summary["step_cost"] else "")
            + ")."
            if costed
            else "."
        )
    )
    header = ["1-NFE sampler", "alpha / lambda", "energy distance (mean ± std)", "per seed", "/ teacher 10-NFE"]
    header += ["95% interval", "coverage error", "cost per row"] + (["step cost / first"] if costed else [])
    teacher = summary[TEACHER_10.name]

    def reference_row(label: str, entry: dict[str, Any]) -> list[str]:
        ratio = np.divide(entry["per_seed"], teacher["per_seed"])
        return [
            label,
            "",
            f"{entry['mean']:.3f} ± {entry['std']:.3f}",
            " / ".join(f"{value:.3f}" for value in entry["per_seed"]),
            f"{np.mean(ratio):.2f}",
            "",
            f"{entry['coverage_error_mean']:.3f}",
            "",
        ] + ([""] if costed else [])

    cells = [reference_row("teacher 10-NFE", teacher), reference_row("naive 1-NFE", summary[NAIVE_1.name])]
    for row in rows:
        low, high = row["ratio_to_teacher_interval"]
        cells.append(
            [
                row["label"],
                f"{row['alpha']:g} / {row['consistency_weight']:g}",
                f"{row['distance_mean']:.3f} ± {row['distance_std']:.3f}",
                " / ".join(f"{value:.3f}" for value in row["distance_per_seed"]),
                f"{row['ratio_to_teacher_mean']:.2f}",
                f"{low:.2f} to {high:.2f}",
                f"{row['coverage_error_mean']:.3f}",
                f"{row['teacher_passes_per_row']:.3g} + {row['student_rows_per_row']}",
            ]
            + ([f"{row['step_cost_ratio']:.2f}"] if costed else [])
        )
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


__all__ = ["RowOption", "ToyJob", "compare_targets", "markdown_comparison", "markdown_coverage", "plot_comparison"]
