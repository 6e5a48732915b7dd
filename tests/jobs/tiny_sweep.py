"""A tiny two-task Meta-World sweep's config, written into a test's folder, and the few words each of its jobs is
named by in the tests of `snapflow sweep`."""

from __future__ import annotations

from pathlib import Path

from snapflow.jobs.runner import Job, write_record
from snapflow.jobs.sweep import CollectJob, DataJob, EvalJob, TrainJob, load_sweep, plan

ROOT = Path(__file__).resolve().parents[2]
TINY_POLICY = "{ prefix_width = 32, expert_width = 32, num_layers = 1, num_heads = 2, head_dim = 16 }"
TINY_TRAIN = (
    "{ steps = 12, batch_size = 16, warmup_steps = 2, log_every = 4, validate_every = 6, checkpoint_every = 6 }"
)


def write_config(
    directory: Path,
    seeds: str = "[0, 1]",
    extra_rows: str = "",
    teacher_policy: str = TINY_POLICY,
    teacher_train: str = TINY_TRAIN,
    snapflow_distill: str = "{ target_steps = [2, 4] }",
    snapflow_train: str = TINY_TRAIN,
    meanflow_distill: str = '{ method = "meanflow" }',
    commit_checkpoint: bool = False,
    max_episode_steps: int | None = None,
) -> Path:
    """The tiny sweep's config in ``directory``, its runs' and tables' settings as given; ``max_episode_steps`` cuts
    every table's episodes there (the runs that evaluate for real: their tiny policies succeed in no episode)."""
    path = directory / "tiny.toml"
    cut = "" if max_episode_steps is None else f"\nmax_episode_steps = {max_episode_steps}"
    path.write_text(f"""
name = "tiny"
title = "two tasks, tiny policies"
seeds = {seeds}
output_dir = "{(directory / "runs").as_posix()}"
results_dir = "{(directory / "results").as_posix()}"

[data]
tasks = ["reach-v3", "push-v3"]
episodes_per_task = 3

[runs.teacher]
policy = {teacher_policy}
train = {teacher_train}
commit_checkpoint = {str(commit_checkpoint).lower()}
[runs.snapflow]
teacher = "teacher"
distill = {snapflow_distill}
train = {snapflow_train}
[runs.meanflow]
teacher = "teacher"
distill = {meanflow_distill}
train = {TINY_TRAIN}
seeds = [0]

[[tables]]
name = "headline"
title = "tiny headline"
episodes_per_task = 2{cut}
per_task = true
rows = [
  {{ label = "teacher 10-NFE", run = "teacher", mode = "teacher-10" }},
  {{ label = "SnapFlow 1-NFE", run = "snapflow", mode = "snapflow-1" }},{extra_rows}
]

[[tables]]
name = "nfe"
x_label = "NFE"
seeds = [0]
episodes_per_task = 2{cut}
rows = [
  {{ label = "teacher 1", run = "teacher", mode = "teacher-1", series = "teacher", x = 1 }},
  {{ label = "teacher 2", run = "teacher", mode = "teacher-2", series = "teacher", x = 2 }},
  {{ label = "MeanFlow 1", run = "meanflow", mode = "snapflow-1", series = "MeanFlow", x = 1 }},
]
""")
    return path


def names(planned: list[Job]) -> set[tuple]:
    """What each job is, in a few words: ("collect", task), ("data",), ("train", run, seed), ("eval", run, seed, mode)."""

    def name(job: Job) -> tuple:
        if isinstance(job, CollectJob):
            return ("collect", *job.data.tasks)
        if isinstance(job, DataJob):
            return ("data",)
        if isinstance(job, TrainJob):
            return ("train", job.run_name, job.seed)
        assert isinstance(job, EvalJob)
        return ("eval", job.policy.run_name, job.policy.seed, job.mode.name)

    return {name(job) for job in planned}


def finish(directory: Path, **changes: str) -> set[tuple]:
    """Mark every job of the tiny sweep finished, as the runner would; then plan it again with ``changes``."""
    for job in plan(load_sweep(write_config(directory))):
        write_record(job)
    assert plan(load_sweep(write_config(directory))) == [], "finished jobs are done"
    return names(plan(load_sweep(write_config(directory, **changes))))


ALL_EVALS = {
    ("eval", "teacher", 0, "teacher-10"),
    ("eval", "teacher", 1, "teacher-10"),
    ("eval", "snapflow", 0, "snapflow-1"),
    ("eval", "snapflow", 1, "snapflow-1"),
    ("eval", "teacher", 0, "naive-1"),  # teacher-1 is the naive step
    ("eval", "teacher", 0, "teacher-2"),
    ("eval", "meanflow", 0, "snapflow-1"),
}
DATA = {("collect", "reach-v3"), ("collect", "push-v3"), ("data",)}
ALL_TRAINS = {
    ("train", "teacher", 0),
    ("train", "teacher", 1),
    ("train", "snapflow", 0),
    ("train", "snapflow", 1),
    ("train", "meanflow", 0),
}
