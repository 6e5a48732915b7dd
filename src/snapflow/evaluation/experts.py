"""How often a benchmark's own scripted experts succeed, per task: the ceiling a policy trained on their
demonstrations is measured against, and the check that a task's expert works at all before demonstrations of it
are asked for (``snapflow experts``)."""

from __future__ import annotations

import resource
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass
from multiprocessing import get_context
from pathlib import Path
from typing import Any

import numpy as np
from tqdm.auto import tqdm

from snapflow.data.collect import expert_episode
from snapflow.envs.base import Benchmark
from snapflow.errors import InvalidInputError
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
    benchmark.check_episodes(split, episodes_per_task)


@dataclass(frozen=True)
class TaskExperts:
    """One task's expert episodes, with the wall time of each and the peak memory of the process that ran them."""

    results: list[EpisodeResult]
    episode_seconds: list[float]
    peak_rss_mb: float


def task_experts(benchmark: Benchmark, task: str, split: str, episodes_per_task: int) -> TaskExperts:
    """``task``'s scripted expert on the first ``episodes_per_task`` variations of ``split``, one episode each."""
    env, expert = benchmark.make_env(task, split), benchmark.make_expert(task)
    results, seconds = [], []
    try:
        for variation in range(episodes_per_task):
            start = time.perf_counter()
            episode = expert_episode(env, expert, variation)
            seconds.append(time.perf_counter() - start)
            results.append(EpisodeResult(task, variation, episode.success, len(episode.actions)))
    finally:
        env.close()
    return TaskExperts(results, seconds, resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024)


def expert_success(
    benchmark: Benchmark,
    tasks: list[str],
    split: str = "eval",
    episodes_per_task: int = 50,
    progress: bool = True,
    workers: int = 1,
) -> list[TaskExperts]:
    """:func:`task_experts` of each task, in order; ``workers`` > 1 runs tasks side by side, each in a process of
    its own (spawned afresh: a simulator's memory is not handed back within a process)."""
    _check(benchmark, tasks, split, episodes_per_task)
    if workers < 1:
        raise InvalidInputError(f"workers must be at least 1, got {workers}")
    with tqdm(total=len(tasks), desc="scripted experts (tasks)", disable=not progress) as bar:
        if workers == 1:
            done = []
            for task in tasks:
                done.append(task_experts(benchmark, task, split, episodes_per_task))
                bar.update()
            return done
        context = get_context("spawn")
        with ProcessPoolExecutor(max_workers=workers, mp_context=context, max_tasks_per_child=1) as pool:
            futures = [pool.submit(task_experts, benchmark, task, split, episodes_per_task) for task in tasks]
            for future in as_completed(futures):
                future.result()  # a failed task stops the run here
                bar.update()
            return [future.result() for future in futures]


def expert_report(
    benchmark: Benchmark, split: str, task_runs: list[TaskExperts], seconds: float, workers: int = 1
) -> dict[str, Any]:
    """``experts.json``: per task (and ``mean``, the mean of the tasks' rates) successes, episodes, rate, 95% Wilson
    interval, mean episode length and wall time per episode; the run's wall time and peak memory per process."""
    results = [result for run in task_runs for result in run.results]
    episode_seconds = {run.results[0].task: run.episode_seconds for run in task_runs}
    counts = success_by_task(results)

    def entry(task: str, count: SuccessCount) -> dict[str, Any]:
        steps = [result.steps for result in results if task in ("mean", result.task)]
        return {
            "successes": count.successes,
            "episodes": count.episodes,
            "success_rate": count.success_rate,
            "interval": list(wilson_interval(count.successes, count.episodes)),
            "mean_steps": sum(steps) / len(steps),
            "seconds_per_episode": float(
                np.mean(episode_seconds[task] if task != "mean" else sum(episode_seconds.values(), []))
            ),
        }

    tasks = {task: entry(task, count) for task, count in counts.items()}
    return {
        "env": benchmark.name,
        "split": split,
        "episodes_per_task": counts[results[0].task].episodes,
        "tasks": tasks,
        "sets": set_means(benchmark, tasks),
        "wall_time_s": seconds,
        "workers": workers,
        # the largest peak resident memory of a process that ran a task's episodes (one environment each)
        "peak_rss_mb": max(run.peak_rss_mb for run in task_runs),
        "machine": machine(),
    }


def set_means(benchmark: Benchmark, tasks: dict[str, dict[str, Any]]) -> dict[str, dict[str, Any]]:
    """For each named task set of ``benchmark`` whose every task ran (LIBERO's suites): the mean of its tasks' rates,
    its successes and episodes, and its lowest task's rate."""
    means = {}
    for name, members in benchmark.task_sets.items():
        if len(members) > 1 and all(task in tasks for task in members):
            entries = [tasks[task] for task in members]
            means[name] = {
                "success_rate": float(np.mean([entry["success_rate"] for entry in entries])),
                "successes": sum(entry["successes"] for entry in entries),
                "episodes": sum(entry["episodes"] for entry in entries),
                "lowest_task_rate": min(entry["success_rate"] for entry in entries),
            }
    return means


def expert_markdown(report: dict[str, Any]) -> str:
    tasks = report["tasks"]
    rows = [
        [
            task,
            f"{entry['successes']} / {entry['episodes']}",
            f"{100 * entry['success_rate']:.1f}",
            "{:.1f}-{:.1f}".format(*(100 * bound for bound in entry["interval"])),
            f"{entry['mean_steps']:.0f}",
            f"{entry['seconds_per_episode']:.1f}",
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
            f"{report['wall_time_s']:.0f} s with {report.get('workers', 1)} worker process(es) on "
            f"{machine_description()}; {mean['seconds_per_episode']:.1f} s an episode, peak memory "
            f"{report.get('peak_rss_mb', float('nan')):.0f} MB a process (one environment).",
            "",
            markdown_table(
                ["task", "successes / episodes", "success %", "95% interval", "mean steps", "s / episode"], rows
            ),
            *(
                [
                    "",
                    "Per set: "
                    + "; ".join(
                        f"{name} **{100 * entry['success_rate']:.1f}%** ({entry['successes']} / {entry['episodes']}, "
                        f"lowest task {100 * entry['lowest_task_rate']:.0f}%)"
                        for name, entry in report["sets"].items()
                    )
                    + ".",
                ]
                if report.get("sets")
                else []
            ),
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
    workers: int = 1,
) -> dict[str, Any]:
    """:func:`expert_success`, written to ``output/experts.{json,md}`` (checked before the folder is made)."""
    _check(benchmark, tasks, split, episodes_per_task)
    with hold_run_lock(output, "snapflow experts"):
        start = time.perf_counter()
        task_runs = expert_success(benchmark, tasks, split, episodes_per_task, progress, workers)
        report = expert_report(benchmark, split, task_runs, time.perf_counter() - start, workers)
        write_json(Path(output) / EXPERTS_JSON, report)
        write_text(Path(output) / EXPERTS_MD, expert_markdown(report))
    return report


__all__ = [
    "EXPERTS_JSON",
    "EXPERTS_MD",
    "TaskExperts",
    "task_experts",
    "expert_success",
    "expert_report",
    "expert_markdown",
    "run_experts",
]
