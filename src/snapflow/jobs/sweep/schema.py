"""A sweep's TOML file read into a typed, checked :class:`SweepConfig`; every mistake is a ValueError naming its
section and key."""

from __future__ import annotations

import re
import tomllib
from pathlib import Path
from typing import Any

from snapflow.adapters.lerobot_config import VIDEO_CODECS, VideoEncoding
from snapflow.data.demonstrations import check_action_noise
from snapflow.envs.factory import DEFAULT_BENCHMARK, make_benchmark
from snapflow.errors import InvalidInputError
from snapflow.evaluation.config import N_ACT
from snapflow.families import FAMILIES, family_of
from snapflow.flow.modes import SamplingMode
from snapflow.flow.realtime_settings import RealTimeChunking
from snapflow.jobs.demo import EVAL_EPISODES
from snapflow.jobs.sweep.specs import (
    EVALUATORS,
    TRAINERS,
    DataSpec,
    RowSpec,
    RunSpec,
    SweepConfig,
    TableSpec,
)
from snapflow.jobs.sweep.table_checks import check_lerobot_eval, first_variation, table_tasks
from snapflow.reporting.settings_tables import checked_count, checked_table, dataclass_from, field_names
from snapflow.training.config import TEACHER_TRAINING
from snapflow.training.recipes import DEFAULT_RECIPE, RECIPES, Recipe


def _seeds(section: str, value: Any) -> tuple[int, ...]:
    if (
        not isinstance(value, list)
        or not value
        or not all(isinstance(seed, int) and not isinstance(seed, bool) for seed in value)
    ):
        raise InvalidInputError(f"{section}: seeds must be a non-empty list of integers, got {value!r}")
    return tuple(value)


def _data(raw: Any) -> DataSpec:
    entry = dict(checked_table("[data]", raw, field_names(DataSpec)))
    try:
        benchmark = make_benchmark(entry.get("env", DEFAULT_BENCHMARK))
    except (TypeError, ValueError) as error:
        raise InvalidInputError(f"[data] env: {error}") from None
    try:
        entry["tasks"] = tuple(benchmark.resolve_tasks(entry["tasks"]) if "tasks" in entry else benchmark.default_tasks)
    except (TypeError, ValueError) as error:
        raise InvalidInputError(f"[data] tasks: {error}") from None
    for name in ("episodes_per_task", "image_size"):
        if entry.get(name) is not None:
            checked_count("[data]", name, entry[name])
    if "extra_cameras" in entry:
        cameras = entry["extra_cameras"]
        if not isinstance(cameras, list) or not all(isinstance(name, str) for name in cameras):
            raise InvalidInputError(f"[data] extra_cameras must be a list of camera names, got {cameras!r}")
        try:
            entry["extra_cameras"] = benchmark.check_cameras(cameras)
        except ValueError as error:
            raise InvalidInputError(f"[data] extra_cameras: {error}") from None
    if "action_noise" in entry:
        try:
            entry["action_noise"] = check_action_noise(entry["action_noise"])
        except ValueError as error:
            raise InvalidInputError(f"[data] {error}") from None
    if "video" in entry:  # a table of VideoEncoding's settings ({} for its defaults), for frames of an image_size
        entry["video"] = dataclass_from("[data] video", VideoEncoding(), entry["video"])
        if entry["video"].codec not in VIDEO_CODECS or entry.get("image_size") is None:
            raise InvalidInputError(f"[data] video: codec one of {list(VIDEO_CODECS)}, and an image_size, needed")
    return dataclass_from("[data]", DataSpec(), entry)


def _recipe(section: str, name: Any) -> Recipe:
    if name not in RECIPES:
        raise InvalidInputError(f"{section}: unknown recipe {name!r}; choose one of {list(RECIPES)}")
    return RECIPES[name]


def _runs(raw: Any, seeds: tuple[int, ...], data: DataSpec, recipe: str) -> dict[str, RunSpec]:
    if not isinstance(raw, dict):
        raise InvalidInputError(f"[runs]: expected a table of keys, got {raw!r}")
    runs: dict[str, RunSpec] = {}
    for name, entry in raw.items():
        section = f"[runs.{name}]"
        allowed = {"teacher", "trainer", "train", "distill", "seeds", "recipe", "commit_checkpoint"}
        allowed |= {family.run_key for family in FAMILIES}
        checked_table(section, entry, allowed)
        run_seeds = _seeds(section, entry.get("seeds", list(seeds)))
        commit_checkpoint = entry.get("commit_checkpoint", False)
        if not isinstance(commit_checkpoint, bool):
            raise InvalidInputError(f"{section}: commit_checkpoint must be true or false, got {commit_checkpoint!r}")
        if "teacher" in entry:
            if given := [family.run_key for family in FAMILIES if family.run_key in entry]:
                raise InvalidInputError(f"{section}: a student takes its policy from its teacher; remove {given}")
            base = _recipe(section, entry.get("recipe", recipe))
            train = dataclass_from(f"{section} train", base.train, entry.get("train", {}))
            train.check_student(f"{section} train")
            settings = dataclass_from(f"{section} distill", base.distill, entry.get("distill", {}))
            trainer = entry.get("trainer", TRAINERS[0])
            if trainer not in TRAINERS:
                raise InvalidInputError(f"{section}: trainer must be one of {list(TRAINERS)}, got {trainer!r}")
            runs[name] = RunSpec(
                name,
                run_seeds,
                train,
                teacher=entry["teacher"],
                distill=settings,
                commit_checkpoint=commit_checkpoint,
                trainer=trainer,
            )
        else:
            if "distill" in entry or "recipe" in entry or "trainer" in entry:
                raise InvalidInputError(
                    f"{section}: 'distill', 'recipe' and 'trainer' need a 'teacher' to distill from"
                )
            train = dataclass_from(f"{section} train", TEACHER_TRAINING, entry.get("train", {}))
            try:
                family = family_of(entry)
            except InvalidInputError as error:
                raise InvalidInputError(f"{section}: {error}") from None
            family.check_teacher_training(f"{section} train", train)
            if data.video is not None and not family.reads_dataset:  # its frames come from the demonstrations then
                raise InvalidInputError(
                    f"{section}: a {family.title} policy cannot read [data] video frames; use 'lerobot'"
                )
            spec = family.teacher_spec(
                f"{section} {family.run_key}", entry.get(family.run_key, {}), data.env, data.tasks
            )
            runs[name] = RunSpec(name, run_seeds, train, spec, commit_checkpoint=commit_checkpoint)
    for run in runs.values():
        if run.teacher is not None:
            teacher = runs.get(run.teacher)
            if teacher is None or teacher.teacher is not None:
                raise InvalidInputError(
                    f"[runs.{run.name}]: teacher {run.teacher!r} is not a teacher run of this sweep"
                )
            if missing := sorted(set(run.seeds) - set(teacher.seeds)):
                raise InvalidInputError(f"[runs.{run.name}]: seeds {missing} have no {run.teacher!r} teacher")
            family = family_of(teacher.spec)
            if run.trainer not in family.trainers:
                raise InvalidInputError(
                    f"[runs.{run.name}]: trainer {run.trainer!r} does not distil {run.teacher!r}, a {family.title} "
                    f"policy; its trainers: {list(family.trainers)}"
                )
    return runs


def _other_sweep(section: str, path: Path, name: Any, data: DataSpec, loading: tuple[Path, ...]) -> SweepConfig:
    """The sweep config ``name`` (relative to ``path``'s folder) that a row reads, on the same benchmark and tasks."""
    if not isinstance(name, str):
        raise InvalidInputError(f"{section}: sweep must be the path of a sweep config, got {name!r}")
    other_path = path.parent / name
    if other_path.resolve() in loading:
        raise InvalidInputError(
            f"{section}: sweep {name!r} reads back a sweep that reads it; sweeps cannot read each other"
        )
    try:
        other = load_sweep(other_path, loading)
    except FileNotFoundError as error:
        raise InvalidInputError(f"{section}: {error}") from None
    if (other.data.env, other.data.tasks) != (data.env, data.tasks):
        raise InvalidInputError(
            f"{section}: sweep {name!r} runs on {other.data.env} {list(other.data.tasks)}, this one on {data.env} "
            f"{list(data.tasks)}: a row pairs with the table's only on the same benchmark and tasks"
        )
    return other


def _rtc(section: str, entry: Any, mode: SamplingMode, n_act: int, run: RunSpec) -> RealTimeChunking:
    """A row's ``rtc = { delay = D, kind = ..., ... }``: :class:`RealTimeChunking`'s fields, checked for its mode, its
    actions a chunk and, for ``trained``, the known prefixes its run was distilled with, before anything trains."""
    checked_table(f"{section}: rtc", entry, field_names(RealTimeChunking), frozenset({"delay"}))
    try:
        rtc = RealTimeChunking(**entry)
        rtc.check_mode(mode)
    except (InvalidInputError, TypeError) as error:
        raise InvalidInputError(f"{section}: rtc: {error}") from None
    if rtc.delay > n_act:
        raise InvalidInputError(f"{section}: rtc: a delay of {rtc.delay} needs delay <= n_act, got n_act {n_act}")
    trained_for = run.distill.rtc_max_delay if run.distill is not None else 0
    if rtc.kind == "trained" and rtc.delay > trained_for:
        raise InvalidInputError(
            f"{section}: rtc: 'trained' at a delay of {rtc.delay} needs run {run.name!r} distilled with rtc_max_delay "
            f"at least {rtc.delay}, got {trained_for}"
        )
    return rtc


def _tables(
    path: Path, raw: Any, seeds: tuple[int, ...], runs: dict[str, RunSpec], data: DataSpec, loading: tuple[Path, ...]
) -> tuple[TableSpec, ...]:
    if not isinstance(raw, list):
        raise InvalidInputError(f"{path}: tables must be a list of [[tables]] entries")
    tables = []
    allowed = {"name", "title", "rows", "seeds", "episodes_per_task", "first_variation", "n_act", "per_task"}
    allowed |= {"x_label", "reference", "evaluator", "tasks", "per_set", "contrasts", "max_episode_steps"}
    for index, entry in enumerate(raw):
        section = f"[[tables]] #{index + 1}"
        checked_table(section, entry, allowed, frozenset({"name", "rows"}))
        table_seeds = _seeds(section, entry.get("seeds", list(seeds)))
        if not isinstance(entry["rows"], list):
            raise InvalidInputError(f"{section}: rows must be a list of {{ label, run, mode }} entries")
        rows = []
        for row in entry["rows"]:
            checked_table(
                f"{section} row",
                row,
                {"label", "run", "mode", "n_act", "series", "x", "sweep", "rtc"},
                frozenset({"label", "run", "mode"}),
            )
            other = None
            if "sweep" in row:
                other = _other_sweep(f"{section}: row {row['label']!r}", path, row["sweep"], data, loading)
            row_runs = runs if other is None else other.runs
            run = row_runs.get(row["run"])
            if run is None:
                where = "" if other is None else f" of sweep {other.name!r}"
                raise InvalidInputError(
                    f"{section}: row {row['label']!r} names unknown run {row['run']!r}{where}; runs: {sorted(row_runs)}"
                )
            if missing := sorted(set(table_seeds) - set(run.seeds)):
                raise InvalidInputError(
                    f"{section}: row {row['label']!r} needs seeds {missing} of run {run.name!r}, which has {list(run.seeds)}"
                )
            try:
                mode = SamplingMode.parse(row["mode"])
            except ValueError as error:
                raise InvalidInputError(f"{section}: row {row['label']!r}: {error}") from None
            if not mode.resolved:
                raise InvalidInputError(
                    f"{section}: row {row['label']!r}: a table states its number of steps: teacher-N, not 'teacher'"
                )
            if mode.jump and run.trainer == "lerobot-train" and not run.distill.trains_jump:
                raise InvalidInputError(  # LeRobot's student labels itself not distilled and refuses the jump
                    f"{section}: row {row['label']!r}: run {run.name!r} trains no jump (alpha 1 or lambda 0): sample "
                    f"it as naive or teacher-N, not {mode}"
                )
            n_act = checked_count(
                f"{section}: row {row['label']!r}", "n_act", row.get("n_act", entry.get("n_act", N_ACT))
            )
            rtc = _rtc(f"{section}: row {row['label']!r}", row["rtc"], mode, n_act, run) if "rtc" in row else None
            rows.append(RowSpec(row["label"], row["run"], mode, n_act, row.get("series"), row.get("x"), other, rtc))
        labels = [row.label for row in rows]
        reference = entry.get("reference")
        if reference is not None and reference not in labels:
            raise InvalidInputError(f"{section}: reference {reference!r} is not one of its rows {labels}")
        contrasts = entry.get("contrasts", [])
        if not isinstance(contrasts, list) or not all(
            isinstance(pair, list) and len(pair) == 2 and set(pair) <= set(labels) for pair in contrasts
        ):
            raise InvalidInputError(f"{section}: contrasts must be [row, against] pairs of its rows {labels}")
        table = TableSpec(
            entry["name"],
            entry.get("title", entry["name"]),
            tuple(rows),
            table_seeds,
            checked_count(section, "episodes_per_task", entry.get("episodes_per_task", EVAL_EPISODES)),
            entry.get("per_task", False),
            entry.get("x_label"),
            reference,
            first_variation(section, entry.get("first_variation", 0)),
            entry.get("evaluator", EVALUATORS[0]),
            table_tasks(section, entry.get("tasks"), data),
            bool(entry.get("per_set", False)),
            tuple(tuple(pair) for pair in contrasts),
            checked_count(section, "max_episode_steps", entry["max_episode_steps"])
            if "max_episode_steps" in entry
            else None,
        )
        if table.evaluator != EVALUATORS[0]:
            if any(row.rtc is not None for row in rows):
                raise InvalidInputError(
                    f"{section}: real-time chunking (a row's rtc) runs on snapflow's evaluator only"
                )
            check_lerobot_eval(section, table, runs, data)
        tables.append(table)
    return tuple(tables)


def load_sweep(path: str | Path, loading: tuple[Path, ...] = ()) -> SweepConfig:
    """Read and check a sweep config; every mistake is a ValueError naming its section and key.

    ``loading``: the configs whose rows read this one (a cycle among them is refused)."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no sweep config at {path}")
    try:
        raw = tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as error:
        raise InvalidInputError(f"{path}: not valid TOML: {error}") from None
    allowed = {"name", "title", "seeds", "output_dir", "results_dir", "data", "runs", "tables", "recipe"}
    checked_table(str(path), raw, allowed, frozenset({"name", "runs", "tables"}))
    name = raw["name"]
    if not isinstance(name, str) or not re.fullmatch(r"[a-z0-9][a-z0-9._-]*", name):
        raise InvalidInputError(f"{path}: name must be lower-case letters, digits, '.', '_' or '-', got {name!r}")
    seeds = _seeds(f"{path}", raw.get("seeds", [0]))
    data = _data(raw.get("data", {}))
    _recipe(str(path), raw.get("recipe", DEFAULT_RECIPE))
    runs = _runs(raw["runs"], seeds, data, raw.get("recipe", DEFAULT_RECIPE))
    return SweepConfig(
        name,
        raw.get("title", name),
        path,
        Path(raw.get("output_dir", f"outputs/sweeps/{name}")),
        Path(raw.get("results_dir", f"docs/results/sweeps/{name}")),
        data,
        runs,
        _tables(path, raw["tables"], seeds, runs, data, (*loading, path.resolve())),
    )


__all__ = ["load_sweep"]
