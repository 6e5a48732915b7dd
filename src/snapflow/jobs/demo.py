"""The main job, ``snapflow demo``: collect -> train the teacher -> SnapFlow-distill -> evaluate -> time, one report."""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

from snapflow.data.collect import EPISODES_PER_TASK, collect
from snapflow.data.demonstrations import META_FILE
from snapflow.envs.factory import DEFAULT_BENCHMARK, make_benchmark
from snapflow.envs.metaworld import MT10_TASKS
from snapflow.evaluation.config import N_ACT
from snapflow.evaluation.pipeline import evaluate
from snapflow.evaluation.report import write_report
from snapflow.evaluation.results import EvaluationReport
from snapflow.flow.modes import NAIVE_1, SNAPFLOW_1, TEACHER_10
from snapflow.policies.checkpoint import load_policy
from snapflow.policies.configuration import PolicyConfig
from snapflow.policies.factory import policy_type
from snapflow.reporting.locks import hold_run_lock
from snapflow.training.config import TEACHER_TRAINING, VAL_FRACTION, TrainConfig
from snapflow.training.recipes import DEFAULT_RECIPE, RECIPES, DistillSettings
from snapflow.training.stages import distill, train_teacher

EVAL_EPISODES = 20  # evaluation episodes per task


@dataclass(frozen=True)
class DemoPreset:
    """Everything the demo runs; ``fast`` is the README default, ``full`` the stronger, longer run. The teacher's
    flow-matching times are ``teacher.time_distribution`` (:class:`~snapflow.training.config.TrainConfig`), recorded
    in its checkpoint and in the report's preset; its student's flow-matching rows draw the same."""

    env: str = DEFAULT_BENCHMARK
    tasks: tuple[str, ...] = MT10_TASKS
    episodes_per_task: int = EPISODES_PER_TASK
    val_fraction: float = VAL_FRACTION
    policy: PolicyConfig = field(default_factory=lambda: policy_type("minivla").config_class())
    teacher: TrainConfig = TEACHER_TRAINING
    student: TrainConfig = RECIPES[DEFAULT_RECIPE].train
    distill: DistillSettings = RECIPES[DEFAULT_RECIPE].distill
    eval_episodes: int = EVAL_EPISODES
    n_act: int = N_ACT


PRESETS: dict[str, DemoPreset] = {
    "fast": DemoPreset(),
    "full": DemoPreset(
        episodes_per_task=50,
        teacher=replace(TEACHER_TRAINING, steps=10000),
        student=replace(RECIPES[DEFAULT_RECIPE].train, steps=2 * RECIPES[DEFAULT_RECIPE].train.steps, warmup_steps=100),
        eval_episodes=50,
    ),
}


def with_recipe(preset: DemoPreset, recipe: str) -> DemoPreset:
    """``preset`` with the student of another recipe (:data:`~snapflow.training.recipes.RECIPES`), at the preset's
    share of that recipe's steps (the full preset trains twice as long)."""
    scale = preset.student.steps / RECIPES[DEFAULT_RECIPE].train.steps
    train = RECIPES[recipe].train
    return replace(
        preset,
        student=replace(train, steps=round(scale * train.steps), warmup_steps=preset.student.warmup_steps),
        distill=RECIPES[recipe].distill,
    )


def run_demo(preset: DemoPreset, output: str | Path, progress: bool = True, resume: bool = False) -> EvaluationReport:
    """collect -> train -> distill -> evaluate; writes ``report.json``, ``report.md`` and PNG plots."""
    output = Path(output)
    if not resume and output.is_dir() and any(output.iterdir()):  # refused at once, not after re-collecting
        raise FileExistsError(f"{output} holds a demo run; continue it with --resume, or choose another --output")
    with hold_run_lock(output, "snapflow demo"):  # its stages lock their own folders; this, the whole demo
        benchmark = make_benchmark(preset.env)
        timings: dict[str, float] = {}
        started = time.perf_counter()
        data, teacher_dir, student_dir = output / "data", output / "teacher", output / "snapflow"
        if not (resume and (data / META_FILE).is_file()):
            collect(benchmark, list(preset.tasks), preset.episodes_per_task, data, progress=progress)
        timings["collect_s"] = time.perf_counter() - started
        train_teacher(
            data, teacher_dir, preset.policy, preset.teacher, preset.val_fraction, resume=resume, progress=progress
        )
        timings["teacher_s"] = time.perf_counter() - started - sum(timings.values())
        distill(
            teacher_dir,
            data,
            student_dir,
            preset.student,
            preset.distill,
            preset.val_fraction,
            resume=resume,
            progress=progress,
        )
        timings["distill_s"] = time.perf_counter() - started - sum(timings.values())
        teacher, student = load_policy(teacher_dir), load_policy(student_dir)
        runs = [
            ("teacher 10-NFE", teacher, TEACHER_10),
            ("naive 1-NFE", teacher, NAIVE_1),
            ("SnapFlow 1-NFE", student, SNAPFLOW_1),
        ]
        report = evaluate(
            runs, benchmark, list(preset.tasks), preset.eval_episodes, preset.n_act, data, progress=progress
        )
        timings["evaluate_s"] = time.perf_counter() - started - sum(timings.values())
        timings["total_s"] = time.perf_counter() - started
        report.timings = timings
        report.preset = {**asdict(replace(preset, policy=None)), "policy": preset.policy.to_dict()}
        write_report(report, output)
    return report


__all__ = ["DemoPreset", "PRESETS", "EVAL_EPISODES", "run_demo", "with_recipe"]
