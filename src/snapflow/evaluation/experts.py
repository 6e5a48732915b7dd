"""How often a benchmark's own scripted experts succeed, per task: the ceiling a policy trained on their
demonstrations is measured against, and the check that a task's expert works at all before demonstrations of it
are asked for (``snapflow experts``)."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

from tqdm.auto import tqdm

from snapflow.data.collect import expert_episode
from snapflow.envs.base import Benchmark
from snapflow.evaluation.results import EpisodeResult, SuccessCount, success_by_task
from snapflow.reporting.files import write_json, write_text
from snapflow.reporting.locks import hold_run_lock
from snapflow.reporting.machine import machine, machine_description
from snapflow.reporting.statistics import wilson_interval
from snapflow.reporting.tables import markdown_table

EXPERTS_JSON = "experts.json"
EXPERTS_MD = "experts.md"


def _check(benchmark: Benchmark, tasks: list[str], split: str, episodes_per_task: int) -> None:
    benchmark.check_tasks(tasks)
    available = benchmark.num_variations(split)  # checks the split too
    if not 1 <= episodes_per_task <= available:
        raise ValueError(f"episodes_per_task must be in [1, {available}] ({split} variations), got {episodes_per_task}")


def expert_success(
    benchmark: Benchmark, tasks: list[str], split: str = "eval", episodes_per_task: int = 50, progress: bool = True
) -> list[EpisodeResult]:
    """Each task's scripted expert on the first ``episodes_per_task`` variations of ``split``, one episode each."""
    _check(benchmark, tasks, split, episodes_per_task)
    results = []
    bar = tqdm(total=len(tasks) * episodes_per_task, desc="scripted experts", disable=not progress)
    for task in tasks:
        env, expert = benchmark.make_env(task, split), benchmark.make_expert(task)
        for variation in range(episodes_per_task):
            _, actions, _, success = expert_episode(env, expert, variation)
            results.append(EpisodeResult(task, variation, success, len(actions)))
            bar.update()
        env.close()
    bar.close()
    return results


def expert_report(benchmark: Benchmark, split: str, results: list[EpisodeResult], seconds: float) -> dict[str, Any]:
    """``experts.json``: per task (and ``mean``, the mean of the tasks' rates) successes, episodes, rate, 95% Wilson
    interval and mean episode length."""
    counts = success_by_task(results)

    def entry(task: str, count: SuccessCount) -> dict[str, Any]:
        steps = [result.steps for result in results if task in ("mean", result.task)]
        return {
            "successes": count.successes,
            "episodes": count.episodes,
            "success_rate": count.success_rate,
            "interval": list(wilson_interval(count.successes, count.episodes)),
            "mean_steps": sum(steps) / len(steps),
        }

    return {
        "env": benchmark.name,
        "split": split,
        "episodes_per_task": counts[results[0].task].episodes,
        "tasks": {task: entry(task, count) for task, count in counts.items()},
        "wall_time_s": seconds,
        "machine": machine(),
    }


def expert_markdown(report: dict[str, Any]) -> str:
    tasks = report["tasks"]
    rows = [
        [
            task,
            f"{entry['successes']} / {entry['episodes']}",
            f"{100 * entry['success_rate']:.1f}",
            "{:.1f}-{:.1f}".format(*(100 * bound for bound in entry["interval"])),
            f"{entry['mean_steps']:.0f}",
        ]
        for task, entry in tasks.items()
    ]
    mean = tasks["mean"]
    return "\n".join(
        [
            f"# Scripted experts of {report['env']}: success per task",
            "",
            f"{len(tasks) - 1} task(s), the first {report['episodes_per_task']} {report['split']} variations of each, "
            f"one episode each; success = the benchmark's own. Mean of the tasks' rates: "
            f"**{100 * mean['success_rate']:.1f}%** ({mean['successes']} / {mean['episodes']} episodes). "
            f"{report['wall_time_s']:.0f} s on {machine_description()}.",
            "",
            markdown_table(["task", "successes / episodes", "success %", "95% interval", "mean steps"], rows),
            "",
        ]
    )


def run_experts(
    benchmark: Benchmark,
    tasks: list[str],
    output: str | Path,
    split: str = "eval",
    episodes_per_task: int = 50,
    progress: bool = True,
) -> dict[str, Any]:
    """:func:`expert_success`, written to ``output/experts.{json,md}`` (checked before the folder is made)."""
    _check(benchmark, tasks, split, episodes_per_task)
    with hold_run_lock(output, "snapflow experts"):
        start = time.perf_counter()
        results = expert_success(benchmark, tasks, split, episodes_per_task, progress)
        report = expert_report(benchmark, split, results, time.perf_counter() - start)
        write_json(Path(output) / EXPERTS_JSON, report)
        write_text(Path(output) / EXPERTS_MD, expert_markdown(report))
    return report


__all__ = ["EXPERTS_JSON", "EXPERTS_MD", "expert_success", "expert_report", "expert_markdown", "run_experts"]
