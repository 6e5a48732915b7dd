"""A sweep's TOML file read into a typed, checked :class:`SweepConfig`; every mistake is a ValueError naming its
section and key."""

from __future__ import annotations

import re
import tomllib
from dataclasses import dataclass, fields, replace
from pathlib import Path
from typing import Any

from snapflow.adapters.lerobot_config import SMOLVLM_SIZES
from snapflow.adapters.lerobot_types import lerobot_teachers
from snapflow.data.collect import EPISODES_PER_TASK
from snapflow.data.demonstrations import check_action_noise
from snapflow.envs.factory import DEFAULT_BENCHMARK, make_benchmark
from snapflow.errors import InvalidInputError
from snapflow.evaluation.config import N_ACT
from snapflow.flow.modes import SamplingMode
from snapflow.jobs.demo import EVAL_EPISODES
from snapflow.policies.configuration import PolicyConfig
from snapflow.policies.factory import default_config, policy_type
from snapflow.reporting.records import added_option
from snapflow.training.config import TEACHER_TRAINING, TrainConfig
from snapflow.training.recipes import DEFAULT_RECIPE, RECIPES, DistillSettings, Recipe

DEFAULT_POLICY = "minivla"


@dataclass(frozen=True)
class DataSpec:
    """The demonstrations every run of the sweep trains on; ``tasks``: all of the benchmark's unless given."""

    env: str = DEFAULT_BENCHMARK
    tasks: tuple[str, ...] = ()
    episodes_per_task: int = EPISODES_PER_TASK
    image_size: int | None = None
    # the benchmark's cameras beside the main one whose frames are stored (None: all; a camera costs its rendering)
    extra_cameras: tuple[str, ...] | None = added_option(None)
    # the standard deviation of the noise added to the experts' executed actions (DART; the recorded actions are the
    # experts' own): states off the experts' paths in the data, labelled with the way back
    action_noise: float = added_option(0.0)


@dataclass(frozen=True)
class LeRobotSpec:
    """A LeRobot policy trained from scratch on the sweep's demonstrations, written as a LeRobotDataset: ``snapflow
    train --policy-type <policy_type>``'s settings (SmolVLA over a SmolVLM of size ``smolvlm`` reading the frames at
    ``image_size``, None: that size's own)."""

    policy_type: str = "smolvla"
    smolvlm: str = "small"
    image_size: int | None = None
    chunk_size: int = 8
    n_action_steps: int = 4


#: how a student of a LeRobot teacher is distilled: snapflow's trainer (``snapflow distill``) or LeRobot's own
#: (``lerobot-train`` on the teacher written as its ``snapflow_<type>`` student)
TRAINERS = ("snapflow", "lerobot-train")
# who runs a table's episodes: snapflow's evaluator (with offline metrics), or LeRobot's own lerobot-eval on LeRobot's
# LIBERO environment, from the same initial states (LeRobot policies only; no offline metrics)
EVALUATORS = ("snapflow", "lerobot-eval")


@dataclass(frozen=True)
class RunSpec:
    """A teacher (``teacher is None``: flow matching on the data, ``policy`` resolved) or a student distilled from
    one; ``train.seed`` is replaced by each of ``seeds``."""

    name: str
    seeds: tuple[int, ...]
    train: TrainConfig
    policy: PolicyConfig | None = None
    teacher: str | None = None
    distill: DistillSettings | None = None
    # its checkpoint kept beside its ledger record, to be committed: the latest while it trains, the policy once it
    # has finished, so a fresh machine continues the run, or distils and evaluates it, instead of training it again
    commit_checkpoint: bool = False
    lerobot: LeRobotSpec | None = None  # a LeRobot teacher (``policy`` is then None); its students are LeRobot's too
    trainer: str = TRAINERS[0]  # a LeRobot teacher's student: which trainer distils it


@dataclass(frozen=True)
class RowSpec:
    label: str
    run: str
    mode: SamplingMode
    n_act: int
    series: str | None = None
    x: float | None = None
    # the sweep whose run the row evaluates, when not the table's own (same benchmark and tasks, so its cells pair
    # with the table's on the same initial states): read from that sweep's records, never run from this one
    sweep: SweepConfig | None = None

    def owner(self, config: SweepConfig) -> SweepConfig:
        """The sweep whose run and evaluations the row reads, in a table of ``config``."""
        return self.sweep if self.sweep is not None else config


@dataclass(frozen=True)
class TableSpec:
    name: str
    title: str
    rows: tuple[RowSpec, ...]
    seeds: tuple[int, ...]
    episodes_per_task: int
    per_task: bool = False
    x_label: str | None = None
    reference: str | None = None  # the row every other is compared with, paired (default: the first)
    first_variation: int = 0  # each task's episodes on its evaluation variations from this one on (LIBERO's states)
    evaluator: str = EVALUATORS[0]  # who runs the episodes: snapflow's evaluator, or LeRobot's own lerobot-eval

    @property
    def reference_row(self) -> RowSpec:
        return next(row for row in self.rows if row.label == (self.reference or self.rows[0].label))


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

    def table_names(self, names: list[str] | None) -> list[str]:
        """``names`` (every table if None), each checked to be one of this sweep's tables."""
        known = [table.name for table in self.tables]
        if names is None:
            return known
        unknown = [name for name in names if name not in known]
        if unknown:
            raise InvalidInputError(f"{self.source}: no table {unknown[0]!r}; its tables are {known}")
        return list(names)

    def only(self, names: list[str] | None) -> SweepConfig:
        """The sweep narrowed to the tables ``names`` (all if None): running it runs only what they need."""
        chosen = self.table_names(names)
        return replace(self, tables=tuple(table for table in self.tables if table.name in chosen))

    @property
    def data_dir(self) -> Path:
        return self.output_dir / "data"

    @property
    def lerobot_dataset_dir(self) -> Path:
        """The demonstrations written as a LeRobotDataset, which the LeRobot runs train on."""
        return self.output_dir / "lerobot"

    def collect_dir(self, task: str) -> Path:
        """Where one task's demonstrations are collected before :attr:`data_dir` puts them together."""
        return self.output_dir / "collect" / task

    def eval_path(
        self,
        run: str,
        seed: int,
        mode: SamplingMode,
        n_act: int,
        episodes_per_task: int,
        first_variation: int = 0,
        evaluator: str = EVALUATORS[0],
    ) -> Path:
        # from the first variation by snapflow's evaluator, the name evaluations had before either could be chosen
        start = f"_from{first_variation}" if first_variation else ""
        by = "" if evaluator == EVALUATORS[0] else f"_{evaluator}"
        name = f"{mode.name}_nact{n_act}_eps{episodes_per_task}{start}{by}.json"
        return self.output_dir / "evals" / run / f"seed-{seed}" / name

    def ledger_path(self, record: Path) -> Path:
        """Where the committed copy of the record at ``record`` (inside :attr:`output_dir`) is kept: under the
        results, so that a fresh checkout continues the sweep instead of repeating what it finished."""
        return self.results_dir / "records" / record.relative_to(self.output_dir)


def _checked(section: str, table: Any, allowed: set[str], required: frozenset[str] = frozenset()) -> dict[str, Any]:
    if not isinstance(table, dict):
        raise InvalidInputError(f"{section}: expected a table of keys, got {table!r}")
    unknown = sorted(set(table) - allowed)
    if unknown:
        raise InvalidInputError(f"{section}: unknown key(s) {unknown}; allowed: {sorted(allowed)}")
    missing = sorted(required - set(table))
    if missing:
        raise InvalidInputError(f"{section}: missing key(s) {missing}")
    return table


def _field_names(cls: type) -> set[str]:
    return {field.name for field in fields(cls)}


def _dataclass_from(section: str, base: Any, overrides: Any) -> Any:
    _checked(section, overrides, _field_names(type(base)))
    try:
        return replace(base, **overrides)
    except (TypeError, ValueError) as error:
        raise InvalidInputError(f"{section}: {error}") from None


def _seeds(section: str, value: Any) -> tuple[int, ...]:
    if (
        not isinstance(value, list)
        or not value
        or not all(isinstance(seed, int) and not isinstance(seed, bool) for seed in value)
    ):
        raise InvalidInputError(f"{section}: seeds must be a non-empty list of integers, got {value!r}")
    return tuple(value)


def _count(section: str, name: str, value: Any) -> int:
    """A count (episodes, actions per chunk, image size): an integer of at least 1, never a silent default."""
    if not isinstance(value, int) or isinstance(value, bool) or value < 1:
        raise InvalidInputError(f"{section}: {name} must be an integer of at least 1, got {value!r}")
    return value


def _data(raw: Any) -> DataSpec:
    entry = dict(_checked("[data]", raw, _field_names(DataSpec)))
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
            _count("[data]", name, entry[name])
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
    return _dataclass_from("[data]", DataSpec(), entry)


def _policy(section: str, raw: Any, data: DataSpec) -> PolicyConfig:
    """The built-in policy ``type`` (default minivla) sized for the data, with the table's other keys applied."""
    name = raw.get("type", DEFAULT_POLICY) if isinstance(raw, dict) else DEFAULT_POLICY
    try:
        config_class = policy_type(name).config_class
    except (TypeError, ValueError) as error:
        raise InvalidInputError(f"{section}: {error}") from None
    overrides = dict(_checked(section, raw, {"type"} | _field_names(config_class)))
    overrides.pop("type", None)
    benchmark = make_benchmark(data.env)
    # a policy field that is also a parameter of default_config (a camera policy's state_dim) goes in its place
    state_dim, action_dim = (
        overrides.pop("state_dim", benchmark.state_dim),
        overrides.pop("action_dim", benchmark.action_dim),
    )
    instructions = [benchmark.instruction(task) for task in data.tasks]
    try:
        return default_config(name, state_dim, action_dim, instructions, **overrides)
    except (TypeError, ValueError) as error:
        raise InvalidInputError(f"{section}: {error}") from None


def _lerobot(section: str, raw: Any) -> LeRobotSpec:
    """A LeRobot teacher's settings, its type one LeRobot trains from scratch here and its SmolVLM a known size."""
    spec = _dataclass_from(section, LeRobotSpec(), raw)
    if spec.policy_type not in lerobot_teachers():
        raise InvalidInputError(
            f"{section}: policy_type must be one LeRobot trains from scratch here, {list(lerobot_teachers())}; "
            f"got {spec.policy_type!r}"
        )
    if spec.smolvlm not in SMOLVLM_SIZES:
        raise InvalidInputError(f"{section}: smolvlm must be one of {list(SMOLVLM_SIZES)}, got {spec.smolvlm!r}")
    for name in ("chunk_size", "n_action_steps", *(("image_size",) if spec.image_size is not None else ())):
        _count(section, name, getattr(spec, name))
    return spec


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
        allowed = {
            "teacher",
            "policy",
            "lerobot",
            "trainer",
            "train",
            "distill",
            "seeds",
            "recipe",
            "commit_checkpoint",
        }
        _checked(section, entry, allowed)
        run_seeds = _seeds(section, entry.get("seeds", list(seeds)))
        commit_checkpoint = entry.get("commit_checkpoint", False)
        if not isinstance(commit_checkpoint, bool):
            raise InvalidInputError(f"{section}: commit_checkpoint must be true or false, got {commit_checkpoint!r}")
        if "teacher" in entry:
            if "policy" in entry or "lerobot" in entry:
                raise InvalidInputError(f"{section}: a student takes its policy from its teacher; remove 'policy'")
            base = _recipe(section, entry.get("recipe", recipe))
            train = _dataclass_from(f"{section} train", base.train, entry.get("train", {}))
            settings = _dataclass_from(f"{section} distill", base.distill, entry.get("distill", {}))
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
            train = _dataclass_from(f"{section} train", TEACHER_TRAINING, entry.get("train", {}))
            if "lerobot" in entry:
                if "policy" in entry:
                    raise InvalidInputError(f"{section}: give 'policy' (a built-in policy) or 'lerobot', not both")
                lerobot = _lerobot(f"{section} lerobot", entry["lerobot"])
                runs[name] = RunSpec(name, run_seeds, train, commit_checkpoint=commit_checkpoint, lerobot=lerobot)
                continue
            policy = _policy(f"{section} policy", entry.get("policy", {}), data)
            runs[name] = RunSpec(name, run_seeds, train, policy, commit_checkpoint=commit_checkpoint)
    for run in runs.values():
        if run.teacher is not None:
            teacher = runs.get(run.teacher)
            if teacher is None or teacher.teacher is not None:
                raise InvalidInputError(
                    f"[runs.{run.name}]: teacher {run.teacher!r} is not a teacher run of this sweep"
                )
            if missing := sorted(set(run.seeds) - set(teacher.seeds)):
                raise InvalidInputError(f"[runs.{run.name}]: seeds {missing} have no {run.teacher!r} teacher")
            if run.trainer != TRAINERS[0] and teacher.lerobot is None:
                raise InvalidInputError(
                    f"[runs.{run.name}]: trainer {run.trainer!r} distils a LeRobot teacher; {run.teacher!r} is built in"
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


def _tables(
    path: Path, raw: Any, seeds: tuple[int, ...], runs: dict[str, RunSpec], data: DataSpec, loading: tuple[Path, ...]
) -> tuple[TableSpec, ...]:
    if not isinstance(raw, list):
        raise InvalidInputError(f"{path}: tables must be a list of [[tables]] entries")
    tables = []
    allowed = {"name", "title", "rows", "seeds", "episodes_per_task", "first_variation", "n_act", "per_task"}
    allowed |= {"x_label", "reference", "evaluator"}
    for index, entry in enumerate(raw):
        section = f"[[tables]] #{index + 1}"
        _checked(section, entry, allowed, frozenset({"name", "rows"}))
        table_seeds = _seeds(section, entry.get("seeds", list(seeds)))
        if not isinstance(entry["rows"], list):
            raise InvalidInputError(f"{section}: rows must be a list of {{ label, run, mode }} entries")
        rows = []
        for row in entry["rows"]:
            _checked(
                f"{section} row",
                row,
                {"label", "run", "mode", "n_act", "series", "x", "sweep"},
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
            n_act = _count(f"{section}: row {row['label']!r}", "n_act", row.get("n_act", entry.get("n_act", N_ACT)))
            rows.append(RowSpec(row["label"], row["run"], mode, n_act, row.get("series"), row.get("x"), other))
        reference = entry.get("reference")
        if reference is not None and reference not in [row.label for row in rows]:
            raise InvalidInputError(
                f"{section}: reference {reference!r} is not one of its rows {[row.label for row in rows]}"
            )
        table = TableSpec(
            entry["name"],
            entry.get("title", entry["name"]),
            tuple(rows),
            table_seeds,
            _count(section, "episodes_per_task", entry.get("episodes_per_task", EVAL_EPISODES)),
            entry.get("per_task", False),
            entry.get("x_label"),
            reference,
            _first_variation(section, entry.get("first_variation", 0)),
            entry.get("evaluator", EVALUATORS[0]),
        )
        if table.evaluator != EVALUATORS[0]:
            _check_lerobot_eval(section, table, runs, data)
        tables.append(table)
    return tuple(tables)


def _check_lerobot_eval(section: str, table: TableSpec, runs: dict[str, RunSpec], data: DataSpec) -> None:
    """A table that ``lerobot-eval`` runs: LeRobot runs of this sweep on LIBERO, each task's episodes one batch from
    its first initial states (:mod:`snapflow.evaluation.lerobot_eval`)."""
    from snapflow.evaluation.lerobot_eval import MAX_EPISODES

    if table.evaluator not in EVALUATORS:
        raise InvalidInputError(f"{section}: evaluator must be one of {list(EVALUATORS)}, got {table.evaluator!r}")
    if data.env != "libero":
        raise InvalidInputError(
            f"{section}: lerobot-eval evaluates on LeRobot's LIBERO environment; data is {data.env!r}"
        )
    if table.first_variation or table.episodes_per_task > MAX_EPISODES:
        raise InvalidInputError(
            f"{section}: lerobot-eval runs a task's episodes as one batch from LIBERO's first initial states: "
            f"first_variation 0 and at most {MAX_EPISODES} episodes a task"
        )
    for row in table.rows:
        run = runs.get(row.run) if row.sweep is None else None
        teacher = runs[run.teacher] if run is not None and run.teacher is not None else run
        if teacher is None or teacher.lerobot is None:
            raise InvalidInputError(
                f"{section}: row {row.label!r}: lerobot-eval evaluates this sweep's LeRobot runs and their students"
            )
        if row.mode.jump and run.teacher is None:
            raise InvalidInputError(f"{section}: row {row.label!r}: a LeRobot teacher has no jump to sample {row.mode}")


def _first_variation(section: str, value: Any) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < 0:
        raise InvalidInputError(f"{section}: first_variation must be an integer of at least 0, got {value!r}")
    return value


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
    _checked(str(path), raw, allowed, frozenset({"name", "runs", "tables"}))
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


__all__ = ["TRAINERS", "DataSpec", "LeRobotSpec", "RunSpec", "RowSpec", "TableSpec", "SweepConfig", "load_sweep"]
