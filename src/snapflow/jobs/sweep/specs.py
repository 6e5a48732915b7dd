"""What a sweep is, typed: its demonstrations, its runs, its tables and their rows, and where each of their files
goes; :mod:`snapflow.jobs.sweep.schema` reads a TOML file into them."""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, replace
from pathlib import Path

from snapflow.adapters.lerobot_config import LeRobotSpec, VideoEncoding
from snapflow.data.collect import EPISODES_PER_TASK
from snapflow.envs.factory import DEFAULT_BENCHMARK
from snapflow.errors import InvalidInputError
from snapflow.flow.modes import SamplingMode
from snapflow.flow.realtime_settings import RealTimeChunking
from snapflow.policies.configuration import PolicyConfig
from snapflow.reporting.records import added_option
from snapflow.training.config import TrainConfig
from snapflow.training.recipes import DistillSettings


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
    # how LeRobot's encoder keeps the frames as video (None: not at all, the tasks' collections not kept): a task's
    # demonstrations, ~30x smaller than as PNG, are then kept beside the sweep's records as they are collected, to be
    # committed; the runs read PNG frames decoded from that video (LeRobot runs only: see schema.py)
    video: VideoEncoding | None = added_option(None)


#: how a student of a LeRobot teacher is distilled: snapflow's trainer (``snapflow distill``) or LeRobot's own
#: (``lerobot-train`` on the teacher written as its ``snapflow_<type>`` student)
TRAINERS = ("snapflow", "lerobot-train")
# who runs a table's episodes: snapflow's evaluator (with offline metrics), or LeRobot's own lerobot-eval on LeRobot's
# LIBERO environment, from the same initial states (LeRobot policies only; no offline metrics)
EVALUATORS = ("snapflow", "lerobot-eval")


@dataclass(frozen=True)
class RunSpec:
    """A teacher (``teacher is None``: flow matching on the data, ``spec`` resolved) or a student distilled from
    one; ``train.seed`` is replaced by each of ``seeds``."""

    name: str
    seeds: tuple[int, ...]
    train: TrainConfig
    # a teacher's policy as its family describes it (a built-in policy's config, a LeRobotSpec): its family's
    spec: PolicyConfig | LeRobotSpec | None = None
    teacher: str | None = None
    distill: DistillSettings | None = None
    # its checkpoint kept beside its ledger record, to be committed: the latest while it trains, the policy once it
    # has finished, so a fresh machine continues the run, or distils and evaluates it, instead of training it again
    commit_checkpoint: bool = False
    trainer: str = TRAINERS[0]  # a student: which of its teacher's family's trainers distils it


def _rtc_name(rtc: RealTimeChunking) -> str:
    """An evaluation's name under real-time chunking: its delay and kind, then a digest of its other settings where
    any differs from its default (numbers as floats: 10 and 10.0 are one setting)."""
    defaults = RealTimeChunking(rtc.delay).to_dict()
    others = {
        key: float(value) if isinstance(value, int | float) and not isinstance(value, bool) else value
        for key, value in rtc.to_dict().items()
        if key not in ("delay", "kind") and value != defaults[key]
    }
    digest = f"-{hashlib.sha1(repr(sorted(others.items())).encode()).hexdigest()[:8]}" if others else ""
    return f"_rtc-d{rtc.delay}-{rtc.kind}{digest}"


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
    # its chunks planned under an inference delay, each continuing the previous one (real-time chunking)
    rtc: RealTimeChunking | None = None

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
    tasks: tuple[str, ...] = ()  # the data's tasks it evaluates, in the data's order (empty: every one)
    per_set: bool = False  # each row also on each named set of the benchmark's tasks (LIBERO's suites)
    # (row, against) label pairs: the first row's success minus the second's, paired, overall and per set
    contrasts: tuple[tuple[str, str], ...] = ()
    max_episode_steps: int | None = None  # every episode cut there (a quick check of a sweep); None: the benchmark's

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

    def tasks_of(self, table: TableSpec) -> tuple[str, ...]:
        """The tasks ``table`` evaluates: its own subset, or every task of the data."""
        return table.tasks or self.data.tasks

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
        tasks: tuple[str, ...] = (),
        max_episode_steps: int | None = None,
        rtc: RealTimeChunking | None = None,
    ) -> Path:
        # from the first variation by snapflow's evaluator on every task, the name evaluations had before any of
        # these could be chosen; a cut one by its step limit; a subset of the tasks is named by its size and a digest of its names
        start = f"_from{first_variation}" if first_variation else ""
        by = "" if evaluator == EVALUATORS[0] else f"_{evaluator}"
        subset = f"_{len(tasks)}tasks-{hashlib.sha1(','.join(tasks).encode()).hexdigest()[:8]}" if tasks else ""
        cut = f"_cut{max_episode_steps}" if max_episode_steps is not None else ""
        realtime = "" if rtc is None else _rtc_name(rtc)
        name = f"{mode.name}_nact{n_act}_eps{episodes_per_task}{start}{by}{subset}{cut}{realtime}.json"
        return self.output_dir / "evals" / run / f"seed-{seed}" / name

    def ledger_path(self, record: Path) -> Path:
        """Where the committed copy of the record at ``record`` (inside :attr:`output_dir`) is kept: under the
        results, so that a fresh checkout continues the sweep instead of repeating what it finished."""
        return self.results_dir / "records" / record.relative_to(self.output_dir)


__all__ = ["DataSpec", "EVALUATORS", "RowSpec", "RunSpec", "SweepConfig", "TRAINERS", "TableSpec"]
