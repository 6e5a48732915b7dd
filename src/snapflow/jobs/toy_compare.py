"""Several distillation settings on the toy mixture, over seeds: which one-step target gets closest to the data.

Each (setting, seed) is one :func:`snapflow.experiments.toy.run_toy_experiment` job, cached as JSON, so an
interrupted comparison resumes; jobs run on spawned worker processes, one thread each. The summary gives,
per setting, the 1-NFE energy distance (mean, sample std, per seed), its ratio to the first setting's and
to the 10-step teacher's, the no-grad passes its target costs per one-step row, and the seconds per step.
"""

from __future__ import annotations

import json
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import asdict, replace
from multiprocessing import get_context
from pathlib import Path
from typing import Any

import numpy as np

from snapflow.jobs.toy import ToyConfig
from snapflow.reporting.files import atomic_write, write_json
from snapflow.reporting.statistics import mean_std
from snapflow.training.distill import TargetOption


def _job(config: ToyConfig, path: str) -> str:
    """Worker entry point: one toy run on one thread, written to ``path``."""
    import torch

    from snapflow.jobs.toy import run_toy_experiment

    torch.set_num_threads(1)
    result = run_toy_experiment(config, progress=False)
    write_json(path, result.to_dict())
    return path


def compare_targets(
    options: list[TargetOption], seeds: list[int], base: ToyConfig, output_dir: str | Path, workers: int = 1, progress: bool = True,
) -> dict[str, Any]:
    """Run what is missing, then write ``comparison.json``, ``comparison.md`` and ``comparison.png``."""
    from tqdm.auto import tqdm

    if not options or not seeds:
        raise ValueError("compare at least one target option on at least one seed")
    if workers < 1:
        raise ValueError(f"workers must be at least 1, got {workers}")
    output_dir = Path(output_dir)
    configs = {(option, seed): replace(base, seed=seed, target=option.target, target_steps=option.steps) for option in options for seed in seeds}
    paths = {key: output_dir / "runs" / key[0].name / f"seed-{key[1]}.json" for key in configs}
    for key, path in paths.items():  # a cached run counts only if it was made with the same settings
        if path.is_file() and json.loads(path.read_text())["config"] != json.loads(json.dumps(asdict(configs[key]))):
            raise ValueError(f"{path} was made with other settings; remove it or choose another output directory")
    missing = [key for key, path in paths.items() if not path.is_file()]
    with ProcessPoolExecutor(max_workers=workers, mp_context=get_context("spawn")) as pool:
        futures = [pool.submit(_job, configs[key], str(paths[key])) for key in missing]
        for future in tqdm(as_completed(futures), total=len(futures), desc="toy runs", disable=not progress):
            future.result()

    runs = {key: json.loads(path.read_text()) for key, path in paths.items()}

    def per_seed(option: TargetOption, name: str) -> list[float]:
        return [runs[(option, seed)]["energy_distance"][name] for seed in seeds]

    teacher, reference = per_seed(options[0], "teacher-10"), per_seed(options[0], "snapflow-1")
    rows = []
    for option in options:
        distances = per_seed(option, "snapflow-1")
        mean, std = mean_std(distances)
        step_ms = [1000 * runs[(option, seed)]["distill_step_s"] for seed in seeds]
        rows.append({
            "option": option.name, "label": option.label, "target": option.target,
            "target_steps": option.steps if isinstance(option.steps, int) else list(option.steps),
            "distance_mean": mean, "distance_std": std, "distance_per_seed": distances,
            "ratio_to_first_mean": float(np.mean(np.divide(distances, reference))),
            "ratio_to_teacher_mean": float(np.mean(np.divide(distances, teacher))),
            "teacher_passes_per_row": option.teacher_passes, "step_ms_median": float(np.median(step_ms)), "step_ms_per_seed": step_ms,
        })
    summary: dict[str, Any] = {"config": {**asdict(base), "seed": None, "target": None, "target_steps": None}, "seeds": seeds}
    for name in ("teacher-10", "naive-1"):  # one teacher per seed, whatever the target
        values = per_seed(options[0], name)
        mean, std = mean_std(values)
        summary[name] = {"mean": mean, "std": std, "per_seed": values}
    summary["rows"] = rows
    write_json(output_dir / "comparison.json", summary)
    atomic_write(output_dir / "comparison.md", lambda temporary: temporary.write_text(markdown_comparison(summary) + "\n"))
    plot_comparison(summary, output_dir / "comparison.png")
    return summary


def markdown_comparison(summary: dict[str, Any]) -> str:
    config, rows = summary["config"], summary["rows"]
    teacher, naive = summary["teacher-10"], summary["naive-1"]
    lines = [
        f"Toy conditional mixture ({config['num_modes']} modes), seeds {', '.join(map(str, summary['seeds']))}; "
        f"{config['distill_steps']} distillation steps, alpha {config['alpha']}, lambda {config['consistency_weight']}, batch {config['batch_size']}; "
        f"energy distance of {config['eval_contexts']} contexts x {config['samples_per_context']} samples to exact samples (lower is better). "
        f"10-step teacher {teacher['mean']:.3f} ± {teacher['std']:.3f}, naive 1-NFE {naive['mean']:.3f} ± {naive['std']:.3f}.",
        "",
        f"| 1-NFE target | energy distance (mean ± std) | per seed | / {rows[0]['label']} | / teacher 10-NFE | no-grad passes per row | ms per step (median) |",
        "|---|---|---|---|---|---|---|",
    ]
    for row in rows:
        per_seed = " / ".join(f"{value:.3f}" for value in row["distance_per_seed"])
        lines.append(f"| {row['label']} | {row['distance_mean']:.3f} ± {row['distance_std']:.3f} | {per_seed} | {row['ratio_to_first_mean']:.2f} | "
                     f"{row['ratio_to_teacher_mean']:.2f} | {row['teacher_passes_per_row']:.3g} + 1 | {row['step_ms_median']:.1f} |")
    return "\n".join(lines)


def plot_comparison(summary: dict[str, Any], path: Path) -> None:
    """Bars: 1-NFE distance per target (mean ± std over seeds), with the teacher's and the naive step's levels."""
    from snapflow.reporting.figures import pyplot

    plt = pyplot()
    rows = summary["rows"]
    figure, axis = plt.subplots(figsize=(6.4, 3.8))
    positions = np.arange(len(rows))
    axis.bar(positions, [row["distance_mean"] for row in rows], yerr=[row["distance_std"] for row in rows], capsize=4, color="#4c72b0")
    for name, style in (("teacher-10", "--"), ("naive-1", ":")):
        axis.axhline(summary[name]["mean"], color="black", linestyle=style, label=f"{name} ({summary[name]['mean']:.3f})")
    axis.set_xticks(positions, [row["label"] for row in rows], rotation=20, ha="right")
    axis.set_ylabel("1-NFE energy distance to the data")
    axis.set_title(f"One-step targets on the toy mixture ({len(summary['seeds'])} seeds)", fontsize=9)
    axis.legend(fontsize=8)
    axis.grid(alpha=0.3, axis="y")
    figure.tight_layout()
    atomic_write(path, lambda temporary: figure.savefig(temporary, dpi=120, format="png"))
    plt.close(figure)


__all__ = ["compare_targets", "markdown_comparison", "plot_comparison"]
