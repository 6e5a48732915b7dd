"""The checks of a sweep table's settings that read more than its own entry: which evaluator runs it, on which of the
data's tasks, from which initial state (read by :mod:`snapflow.jobs.sweep.schema`)."""

from __future__ import annotations

from typing import Any

from snapflow.envs.factory import make_benchmark
from snapflow.envs.libero import Libero
from snapflow.errors import InvalidInputError
from snapflow.families import FAMILIES, family_of
from snapflow.jobs.sweep.specs import EVALUATORS, DataSpec, RunSpec, TableSpec


def check_lerobot_eval(section: str, table: TableSpec, runs: dict[str, RunSpec], data: DataSpec) -> None:
    """A table that ``lerobot-eval`` runs: LeRobot runs of this sweep on LIBERO, each task's episodes one batch from
    its first initial states (:mod:`snapflow.evaluation.lerobot_eval`)."""
    from snapflow.evaluation.lerobot_eval import MAX_EPISODES

    if table.evaluator not in EVALUATORS:
        raise InvalidInputError(f"{section}: evaluator must be one of {list(EVALUATORS)}, got {table.evaluator!r}")
    if not isinstance(make_benchmark(data.env), Libero):
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
        if teacher is None or table.evaluator not in family_of(teacher.spec).evaluators:
            raise InvalidInputError(
                f"{section}: row {row.label!r}: {table.evaluator} evaluates this sweep's "
                f"{' and '.join(family.title for family in FAMILIES if table.evaluator in family.evaluators)} runs "
                "and their students"
            )
        if row.mode.jump and run.teacher is None:
            raise InvalidInputError(f"{section}: row {row.label!r}: a LeRobot teacher has no jump to sample {row.mode}")


def table_tasks(section: str, value: Any, data: DataSpec) -> tuple[str, ...]:
    """A table's subset of the data's tasks (task names or the benchmark's sets, e.g. ``"libero_10"``), in the data's
    order; empty where it names none or all of them, so that such a table shares every other one's evaluations."""
    if value is None:
        return ()
    try:
        chosen = set(make_benchmark(data.env).resolve_tasks(value))
    except (TypeError, ValueError) as error:
        raise InvalidInputError(f"{section}: tasks: {error}") from None
    if outside := sorted(chosen - set(data.tasks)):
        raise InvalidInputError(f"{section}: tasks {outside} are not among the data's, whose demonstrations it needs")
    return () if chosen == set(data.tasks) else tuple(task for task in data.tasks if task in chosen)


def first_variation(section: str, value: Any) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < 0:
        raise InvalidInputError(f"{section}: first_variation must be an integer of at least 0, got {value!r}")
    return value


__all__ = ["check_lerobot_eval", "first_variation", "table_tasks"]
