"""Sweeps: the paper's experiments on MT10 from one TOML file, with seeds, caching and a report.

A sweep config names a demonstration set, the runs trained on it (teachers, and students distilled from
them, each with its own settings and seeds) and the tables to fill (rows = run x sampling mode x actions
per chunk). ``run_sweeps`` does whatever is missing, in dependency order and on several worker processes:
collect -> train teachers -> distill students -> evaluate. Every finished piece is a file under the
sweep's ``output_dir``, so an interrupted sweep picks up where it stopped, and adding a seed or a row only
runs what is new. ``write_results`` then turns the cached evaluations into ``results.json``, one PNG per
table and Markdown tables, which it writes between markers in a results document (``docs/RESULTS.md``)
and leaves the prose around them alone.

Config layout (see ``configs/sweeps/*.toml``)::

    name = "mt10-state"                 # output_dir = outputs/sweeps/<name>, results in docs/results/sweeps/<name>
    seeds = [0, 1, 2]                   # default seeds of every run and table
    [data]                              # tasks ("all" or a list), episodes_per_task, image_size, via_points
    [runs.teacher]                      # a teacher: policy = {MiniVLAConfig fields}, train = {TrainConfig fields}
    [runs.snapflow]                     # a student: teacher = "teacher", distill = {DistillSettings fields}, train
    [[tables]]                          # name, title, episodes_per_task, n_act, seeds, per_task, x_label
    rows = [{label = "...", run = "snapflow", mode = "snapflow-1", n_act = 4, series = "...", x = 1}]
"""

from __future__ import annotations

import json
import os
import re
import time
import tomllib
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from dataclasses import asdict, dataclass, fields, replace
from multiprocessing import get_context
from pathlib import Path
from typing import Any

import numpy as np

from snapflow.data.demonstrations import META_FILE
from snapflow.envs.metaworld import MT10_TASKS
from snapflow.flow.solver import SamplingMode
from snapflow.reporting.files import atomic_write, write_json
from snapflow.reporting.statistics import mean_std
from snapflow.policies.minivla import MiniVLAConfig
from snapflow.training.distill import DistillSettings
from snapflow.training.trainer import HISTORY, TrainConfig


@dataclass(frozen=True)
class DataSpec:
    tasks: tuple[str, ...] = MT10_TASKS
    episodes_per_task: int = 30
    image_size: int | None = None
    via_points: bool = False


@dataclass(frozen=True)
class RunSpec:
    """A teacher (``teacher is None``: flow matching on the data) or a student distilled from one."""

    name: str
    seeds: tuple[int, ...]
    train: TrainConfig
    policy: MiniVLAConfig | None = None
    teacher: str | None = None
    distill: DistillSettings | None = None


@dataclass(frozen=True)
class RowSpec:
    label: str
    run: str
    mode: SamplingMode
    n_act: int
    series: str | None = None
    x: float | None = None


@dataclass(frozen=True)
class TableSpec:
    name: str
    title: str
    rows: tuple[RowSpec, ...]
    seeds: tuple[int, ...]
    episodes_per_task: int
    per_task: bool = False
    x_label: str | None = None


@dataclass(frozen=True)
class SweepConfig:
    name: str
    title: str
    source: Path
    output_dir: Path
    results_dir: Path
    data: DataSpec
    runs: dict[str, RunSpec]
    tables: tuple[TableSpec, ...]

    def run_dir(self, run: str, seed: int) -> Path:
        return self.output_dir / run / f"seed-{seed}"

    @property
    def data_dir(self) -> Path:
        return self.output_dir / "data"


def _checked(section: str, table: Any, allowed: set[str], required: set[str] = frozenset()) -> dict[str, Any]:
    if not isinstance(table, dict):
        raise ValueError(f"{section}: expected a table of keys, got {table!r}")
    unknown = sorted(set(table) - allowed)
    if unknown:
        raise ValueError(f"{section}: unknown key(s) {unknown}; allowed: {sorted(allowed)}")
    missing = sorted(required - set(table))
    if missing:
        raise ValueError(f"{section}: missing key(s) {missing}")
    return table


def _dataclass_from(section: str, cls: type, base: Any, overrides: dict[str, Any]) -> Any:
    _checked(section, overrides, {field.name for field in fields(cls)})
    try:
        return replace(base, **overrides)
    except (TypeError, ValueError) as error:
        raise ValueError(f"{section}: {error}") from None


def _seeds(section: str, value: Any) -> tuple[int, ...]:
    if not isinstance(value, list) or not value or not all(isinstance(seed, int) and not isinstance(seed, bool) for seed in value):
        raise ValueError(f"{section}: seeds must be a non-empty list of integers, got {value!r}")
    return tuple(value)


def load_sweep(path: str | Path) -> SweepConfig:
    """Read and check a sweep config; every mistake is a ValueError naming its section and key."""
    from snapflow.jobs.demo import PRESETS

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no sweep config at {path}")
    try:
        raw = tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as error:
        raise ValueError(f"{path}: not valid TOML: {error}") from None
    _checked(str(path), raw, {"name", "title", "seeds", "output_dir", "results_dir", "data", "runs", "tables"}, {"name", "runs", "tables"})
    name = raw["name"]
    if not isinstance(name, str) or not re.fullmatch(r"[a-z0-9][a-z0-9._-]*", name):
        raise ValueError(f"{path}: name must be lower-case letters, digits, '.', '_' or '-', got {name!r}")
    seeds = _seeds(f"{path}", raw.get("seeds", [0]))
    preset = PRESETS["fast"]

    data_raw = _checked("[data]", dict(raw.get("data", {})), {field.name for field in fields(DataSpec)})
    if "tasks" in data_raw:
        data_raw["tasks"] = MT10_TASKS if data_raw["tasks"] == "all" else tuple(check_tasks(list(data_raw["tasks"])))
    data = _dataclass_from("[data]", DataSpec, DataSpec(), data_raw)

    runs: dict[str, RunSpec] = {}
    if not isinstance(raw["runs"], dict):
        raise ValueError(f"[runs]: expected a table of keys, got {raw['runs']!r}")
    for run_name, entry in raw["runs"].items():
        section = f"[runs.{run_name}]"
        _checked(section, entry, {"teacher", "policy", "train", "distill", "seeds"})
        run_seeds = _seeds(section, entry.get("seeds", list(seeds)))
        if "teacher" in entry:
            if "policy" in entry:
                raise ValueError(f"{section}: a student takes its policy from its teacher; remove 'policy'")
            runs[run_name] = RunSpec(
                run_name, run_seeds, _dataclass_from(f"{section} train", TrainConfig, preset.student, entry.get("train", {})),
                teacher=entry["teacher"], distill=_dataclass_from(f"{section} distill", DistillSettings, preset.distill, entry.get("distill", {})),
            )
        else:
            if "distill" in entry:
                raise ValueError(f"{section}: 'distill' needs a 'teacher' to distill from")
            policy = _dataclass_from(f"{section} policy", MiniVLAConfig, preset.policy, entry.get("policy", {}))
            runs[run_name] = RunSpec(run_name, run_seeds, _dataclass_from(f"{section} train", TrainConfig, preset.teacher, entry.get("train", {})), policy)
    for run in runs.values():
        if run.teacher is not None:
            teacher = runs.get(run.teacher)
            if teacher is None or teacher.teacher is not None:
                raise ValueError(f"[runs.{run.name}]: teacher {run.teacher!r} is not a teacher run of this sweep")
            if missing := sorted(set(run.seeds) - set(teacher.seeds)):
                raise ValueError(f"[runs.{run.name}]: seeds {missing} have no {run.teacher!r} teacher")

    tables = []
    if not isinstance(raw["tables"], list):
        raise ValueError(f"{path}: tables must be a list of [[tables]] entries")
    for index, entry in enumerate(raw["tables"]):
        section = f"[[tables]] #{index + 1}"
        _checked(section, entry, {"name", "title", "rows", "seeds", "episodes_per_task", "n_act", "per_task", "x_label"}, {"name", "rows"})
        table_seeds = _seeds(section, entry.get("seeds", list(seeds)))
        rows = []
        if not isinstance(entry["rows"], list):
            raise ValueError(f"{section}: rows must be a list of {{ label, run, mode }} entries")
        for row in entry["rows"]:
            _checked(f"{section} row", row, {"label", "run", "mode", "n_act", "series", "x"}, {"label", "run", "mode"})
            if row["run"] not in runs:
                raise ValueError(f"{section}: row {row['label']!r} names unknown run {row['run']!r}; runs: {sorted(runs)}")
            if missing := sorted(set(table_seeds) - set(runs[row["run"]].seeds)):
                raise ValueError(f"{section}: row {row['label']!r} needs seeds {missing} of run {row['run']!r}, which has {list(runs[row['run']].seeds)}")
            n_act = row.get("n_act", entry.get("n_act", preset.n_act))
            rows.append(RowSpec(row["label"], row["run"], SamplingMode.parse(row["mode"]), n_act, row.get("series"), row.get("x")))
        tables.append(TableSpec(entry["name"], entry.get("title", entry["name"]), tuple(rows), table_seeds,
                                entry.get("episodes_per_task", preset.eval_episodes), entry.get("per_task", False), entry.get("x_label")))
    return SweepConfig(name, raw.get("title", name), path, Path(raw.get("output_dir", f"outputs/sweeps/{name}")),
                       Path(raw.get("results_dir", f"docs/results/sweeps/{name}")), data, runs, tuple(tables))


# ---------------------------------------------------------------------------------------------- jobs


@dataclass(frozen=True)
class EvalGroup:
    """One closed-loop evaluation: every mode a sweep asks of one (run, seed, n_act, episodes per task)."""

    run: str
    seed: int
    n_act: int
    episodes_per_task: int
    modes: tuple[str, ...]


def _eval_path(config: SweepConfig, run: str, seed: int, mode: str, n_act: int, episodes: int) -> Path:
    return config.output_dir / "evals" / run / f"seed-{seed}" / f"{mode}_nact{n_act}_eps{episodes}.json"


def _trained(config: SweepConfig, run: str, seed: int) -> bool:
    history = config.run_dir(run, seed) / HISTORY
    return history.is_file() and json.loads(history.read_text())["step"] >= config.runs[run].train.steps


def eval_groups(config: SweepConfig) -> list[EvalGroup]:
    """The evaluations the tables need and that are not cached yet."""
    wanted: dict[tuple[str, int, int, int], set[str]] = {}
    for table in config.tables:
        for row in table.rows:
            for seed in table.seeds:
                if not _eval_path(config, row.run, seed, row.mode.name, row.n_act, table.episodes_per_task).is_file():
                    wanted.setdefault((row.run, seed, row.n_act, table.episodes_per_task), set()).add(row.mode.name)
    return [EvalGroup(run, seed, n_act, episodes, tuple(sorted(modes))) for (run, seed, n_act, episodes), modes in sorted(wanted.items())]


def _collect_job(config: SweepConfig) -> None:
    from snapflow.jobs.demo import collect

    data = config.data
    collect(list(data.tasks), data.episodes_per_task, config.data_dir, data.image_size, progress=False, via_points=data.via_points)


def _train_job(config: SweepConfig, run_name: str, seed: int) -> None:
    from snapflow.jobs.demo import PRESETS, distill, train_teacher

    run = config.runs[run_name]
    train_config = replace(run.train, seed=seed)
    if run.teacher is None:
        train_teacher(config.data_dir, config.run_dir(run_name, seed), run.policy, train_config, PRESETS["fast"].val_fraction, resume=True, progress=False)
    else:
        distill(config.run_dir(run.teacher, seed), config.data_dir, config.run_dir(run_name, seed), train_config, run.distill, resume=True, progress=False)


def _eval_job(config: SweepConfig, group: EvalGroup) -> None:
    from snapflow.jobs.demo import evaluate
    from snapflow.training.checkpoint import load_policy

    loaded = load_policy(config.run_dir(group.run, group.seed))
    runs = [(mode, loaded, SamplingMode.parse(mode)) for mode in group.modes]
    report = evaluate(runs, list(config.data.tasks), group.episodes_per_task, group.n_act, config.data_dir, seed=group.seed,
                      progress=False, via_points=config.data.via_points, timing=False)
    for mode in group.modes:
        write_json(_eval_path(config, group.run, group.seed, mode, group.n_act, group.episodes_per_task),
                   {**report["rows"][mode], "n_act": group.n_act, "episodes_per_task": group.episodes_per_task, "seed": group.seed})


def _run_job(source: str, job: tuple, threads: int) -> tuple[tuple, float]:
    """Worker entry point (a fresh process): re-read the config, run one job, return its wall time."""
    import torch

    torch.set_num_threads(threads)
    config = load_sweep(source)
    started = time.perf_counter()
    kind = job[0]
    if kind == "collect":
        _collect_job(config)
    elif kind == "train":
        _train_job(config, job[1], job[2])
    else:
        _eval_job(config, job[1])
    return job, time.perf_counter() - started


def plan(config: SweepConfig) -> list[tuple[tuple, list[tuple]]]:
    """Jobs still to do, each with the jobs it waits for: collect, train (teachers before their students), eval."""
    jobs: list[tuple[tuple, list[tuple]]] = []
    collect = ("collect",)
    if not (config.data_dir / META_FILE).is_file():
        jobs.append((collect, []))
    pending = {job for job, _ in jobs}
    needed = {(row.run, seed) for table in config.tables for row in table.rows for seed in table.seeds}
    needed |= {(config.runs[run].teacher, seed) for run, seed in needed if config.runs[run].teacher}
    for run, seed in sorted(needed, key=lambda item: (config.runs[item[0]].teacher is not None, item)):
        if not _trained(config, run, seed):
            teacher = config.runs[run].teacher
            job = ("train", run, seed)
            jobs.append((job, [dep for dep in (collect, ("train", teacher, seed)) if dep in pending]))
            pending.add(job)
    for group in eval_groups(config):
        jobs.append((("eval", group), [dep for dep in (collect, ("train", group.run, group.seed)) if dep in pending]))
    return jobs


def _stage(config: SweepConfig, job: tuple) -> int:
    if job[0] == "train":
        return 1 if config.runs[job[1]].teacher is None else 2
    return {"collect": 0, "eval": 3}[job[0]]


def _describe(job: tuple) -> str:
    if job[0] == "collect":
        return "collect demonstrations"
    if job[0] == "train":
        return f"train {job[1]} seed {job[2]}"
    group = job[1]
    return f"evaluate {group.run} seed {group.seed} ({', '.join(group.modes)}; n_act {group.n_act})"


def run_sweeps(configs: list[SweepConfig], workers: int = 1, progress: bool = True) -> dict[str, float]:
    """Run every missing job of the sweeps on ``workers`` processes, stage by stage (collect, teachers,
    students, evaluations; sweeps in the order given within a stage); returns each job's wall time (s)."""
    from tqdm.auto import tqdm

    configs_by_source = {str(config.source): config for config in configs}
    names = {source: config.name for source, config in configs_by_source.items()}
    waiting = [((str(config.source), job), [(str(config.source), dep) for dep in deps]) for config in configs for job, deps in plan(config)]
    # earlier pipeline stages first across all sweeps: their jobs are the longest and unblock the others
    waiting.sort(key=lambda entry: _stage(configs_by_source[entry[0][0]], entry[0][1]))
    threads = max(1, (os.cpu_count() or 1) // workers)
    done: set[tuple] = set()
    times: dict[str, float] = {}
    running: dict[Future, tuple] = {}
    bar = tqdm(total=len(waiting), desc="sweep", disable=not progress, dynamic_ncols=True)

    def describe(key: tuple) -> str:
        return f"{names[key[0]]}: {_describe(key[1])}"

    # spawn: each worker imports torch afresh, with its own thread count and no inherited locks
    with ProcessPoolExecutor(max_workers=workers, mp_context=get_context("spawn")) as pool:
        while waiting or running:
            for entry in [entry for entry in waiting if all(dep in done for dep in entry[1])][: workers - len(running)]:
                waiting.remove(entry)
                running[pool.submit(_run_job, entry[0][0], entry[0][1], threads)] = entry[0]
                bar.write(f"started: {describe(entry[0])}")
            finished, _ = wait(running, return_when=FIRST_COMPLETED)
            for future in finished:
                key = running.pop(future)
                _, seconds = future.result()  # a failed job stops the sweep with its own error
                done.add(key)
                times[describe(key)] = seconds
                bar.write(f"done in {seconds / 60:.1f} min: {describe(key)}")
                bar.update()
    bar.close()
    return times


# ------------------------------------------------------------------------------------------- results


def table_results(config: SweepConfig, table: TableSpec) -> dict[str, Any]:
    """Per row: success over seeds (mean, std, per seed, episode counts), per task, offline metrics, times."""
    rows = []
    for row in table.rows:
        evals = [json.loads(_eval_path(config, row.run, seed, row.mode.name, row.n_act, table.episodes_per_task).read_text()) for seed in table.seeds]
        rates = [100 * e["success"]["mean"]["success_rate"] for e in evals]
        mean, std = mean_std(rates)
        entry: dict[str, Any] = {
            "label": row.label, "run": row.run, "mode": row.mode.name, "nfe": row.mode.num_steps, "n_act": row.n_act,
            "series": row.series, "x": row.x, "seeds": list(table.seeds), "success_mean": mean, "success_std": std,
            "success_per_seed": rates, "successes": sum(e["success"]["mean"]["successes"] for e in evals),
            "episodes": sum(e["success"]["mean"]["episodes"] for e in evals),
            "per_task": {task: float(np.mean([100 * e["success"][task]["success_rate"] for e in evals])) for task in config.data.tasks},
            "evaluation_s": sum(e["closed_loop_s"] for e in evals),
            "training_s": [_training_seconds(config, row.run, seed) for seed in table.seeds],
            "step_s": [_step_seconds(config, row.run, seed) for seed in table.seeds],
        }
        if all("offline" in e for e in evals):
            entry["offline"] = {key: float(np.mean([e["offline"][key] for e in evals])) for key in ("mse", "mse_p90", "mse_p95", "cosine")}
            entry["offline"]["samples"] = evals[0]["offline"]["samples"]
        rows.append(entry)
    return {"name": table.name, "title": table.title, "episodes_per_task": table.episodes_per_task, "seeds": list(table.seeds),
            "x_label": table.x_label, "rows": rows}


def _training_seconds(config: SweepConfig, run: str, seed: int) -> float:
    """Wall time of the run, plus its teacher's for a student (what it took to get the policy)."""
    seconds = json.loads((config.run_dir(run, seed) / HISTORY).read_text())["wall_time_s"]
    teacher = config.runs[run].teacher
    return seconds + (_training_seconds(config, teacher, seed) if teacher else 0.0)


def _step_seconds(config: SweepConfig, run: str, seed: int) -> float:
    """Seconds per training step of the run itself (a student's cost, without its teacher's)."""
    history = json.loads((config.run_dir(run, seed) / HISTORY).read_text())
    return history["wall_time_s"] / history["step"]


def markdown_table(config: SweepConfig, result: dict[str, Any], command: str) -> str:
    rows = result["rows"]
    episodes = rows[0]["episodes"] // len(result["seeds"])
    train_minutes = [np.mean(row["training_s"]) / 60 for row in rows]
    lines = [
        f"**{result['title']}** ({config.title}). `{command}`; seeds {', '.join(map(str, result['seeds']))}; "
        f"{result['episodes_per_task']} episodes per task ({episodes} per seed and row); "
        f"wall time: evaluation {sum(row['evaluation_s'] for row in rows) / 60:.1f} min for the table, training "
        f"{min(train_minutes):.1f}-{max(train_minutes):.1f} min per policy (teacher included).",
        "",
        "| row | NFE | n_act | success % (mean ± std) | per seed | successes / episodes | offline MSE | P95 | cosine | s / training step |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for row in rows:
        offline = row.get("offline")
        metrics = f"{offline['mse']:.4f} | {offline['mse_p95']:.4f} | {offline['cosine']:.3f}" if offline else "- | - | -"
        per_seed = " / ".join(f"{rate:.1f}" for rate in row["success_per_seed"])
        lines.append(f"| {row['label']} | {row['nfe']} | {row['n_act']} | {row['success_mean']:.1f} ± {row['success_std']:.1f} | "
                     f"{per_seed} | {row['successes']} / {row['episodes']} | {metrics} | {np.median(row['step_s']):.3f} |")
    if any(row.get("offline") for row in rows):
        lines += ["", f"Offline metrics: mean over seeds of {rows[0]['offline']['samples']} held-out demonstration chunks per seed "
                      "(normalised actions), the same chunks and noise for every row."]
    lines += ["", "s / training step: median over seeds of the run's own training wall time per step (the teacher's for "
                  "teacher rows), each job on cores / workers threads."]
    return "\n".join(lines)


def markdown_per_task(config: SweepConfig, result: dict[str, Any]) -> str:
    rows = result["rows"]
    lines = ["| task | " + " | ".join(row["label"] for row in rows) + " |", "|---|" + "---|" * len(rows)]
    for task in config.data.tasks:
        lines.append(f"| {task} | " + " | ".join(f"{row['per_task'][task]:.1f}" for row in rows) + " |")
    return "\n".join(lines)


def plot_table(result: dict[str, Any], path: Path) -> None:
    """Success (mean ± std over seeds): lines over ``x`` when the rows carry one, bars otherwise."""
    from snapflow.reporting.figures import pyplot

    plt = pyplot()
    rows = result["rows"]
    figure, axis = plt.subplots(figsize=(6.4, 3.8))
    if all(row["x"] is not None for row in rows):
        for series in dict.fromkeys(row["series"] for row in rows):
            points = sorted((row["x"], row["success_mean"], row["success_std"]) for row in rows if row["series"] == series)
            xs, means, stds = zip(*points, strict=True)
            axis.errorbar(xs, means, yerr=stds, marker="o", capsize=3, label=series or "")
        axis.set_xlabel(result["x_label"] or "x")
        if any(row["series"] for row in rows):
            axis.legend()
    else:
        positions = np.arange(len(rows))
        axis.bar(positions, [row["success_mean"] for row in rows], yerr=[row["success_std"] for row in rows], capsize=4, color="#4c72b0")
        axis.set_xticks(positions, [row["label"] for row in rows], rotation=20, ha="right")
    axis.set_ylabel("MT10 success % (mean ± std over seeds)")
    axis.set_title(f"{result['title']} ({len(result['seeds'])} seed(s), {result['episodes_per_task']} episodes per task)", fontsize=9)
    axis.grid(alpha=0.3)
    figure.tight_layout()
    atomic_write(path, lambda temporary: figure.savefig(temporary, dpi=120, format="png"))
    plt.close(figure)


def replace_block(document: str, key: str, body: str) -> str:
    """Put ``body`` between the ``<!-- sweep:KEY -->`` and ``<!-- /sweep:KEY -->`` markers (appended if absent)."""
    start, end = f"<!-- sweep:{key} -->", f"<!-- /sweep:{key} -->"
    block = f"{start}\n{body}\n{end}"
    pattern = re.compile(re.escape(start) + r".*?" + re.escape(end), re.DOTALL)
    if pattern.search(document):
        return pattern.sub(lambda _: block, document)
    return document.rstrip("\n") + f"\n\n{block}\n"


def write_results(config: SweepConfig, document: str | Path | None = None) -> dict[str, Any]:
    """``results.json``, ``tables.md`` and one PNG per table in the sweep's results_dir; the tables also go
    into ``document`` (between their markers) if given.

    Raises FileNotFoundError naming the first missing evaluation when the sweep has not run to the end.
    """
    results_dir = config.results_dir
    command = f"snapflow sweep {config.source.as_posix()}"
    results: dict[str, Any] = {"sweep": config.name, "title": config.title, "config": config.source.as_posix(),
                               "data": {**asdict(config.data), "tasks": list(config.data.tasks)}, "tables": {}}
    blocks: dict[str, tuple[str, str]] = {}  # key -> (Markdown, PNG file name)
    for table in config.tables:
        try:
            result = table_results(config, table)
        except FileNotFoundError as error:
            raise FileNotFoundError(f"{config.name}: table {table.name!r} is incomplete ({error.filename} missing); run the sweep first") from None
        results["tables"][table.name] = result
        plot_table(result, results_dir / f"{table.name}.png")
        body = markdown_table(config, result, command)
        if table.per_task:
            body += "\n\nPer task, success % (mean over seeds):\n\n" + markdown_per_task(config, result)
        blocks[f"{config.name}/{table.name}"] = (body, f"{table.name}.png")
    write_json(results_dir / "results.json", results)

    def with_plots(directory: Path) -> dict[str, str]:
        link = Path(os.path.relpath(results_dir, directory)).as_posix()
        return {key: f"{body}\n\n![{key}]({link}/{image})" for key, (body, image) in blocks.items()}

    tables = "\n\n".join(f"### {key}\n\n{body}" for key, body in with_plots(results_dir).items())
    atomic_write(results_dir / "tables.md", lambda temporary: temporary.write_text(f"# {config.title}\n\n{tables}\n"))
    if document is not None:
        document = Path(document)
        text = document.read_text() if document.is_file() else "# Results\n"
        for key, body in with_plots(document.parent).items():
            text = replace_block(text, key, body)
        atomic_write(document, lambda temporary: temporary.write_text(text))
    return results


__all__ = ["SweepConfig", "load_sweep", "plan", "run_sweeps", "write_results", "replace_block", "table_results"]
