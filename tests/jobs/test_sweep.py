"""`snapflow sweep`: the config schema, the cache rule keyed by each job's full settings (fast: finished jobs are
records written the way the runner writes them), the Markdown of the committed results, and a tiny sweep run for
real (slow: Meta-World, training, evaluation, files on disk)."""

from __future__ import annotations

import json
import os
import re
import shutil
import signal
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any, ClassVar

import pytest
import torch

from snapflow.cli import main
from snapflow.errors import SnapflowError
from snapflow.jobs.runner import Job, is_done, is_recorded, read_record, run_jobs, to_run, write_record
from snapflow.jobs.sweep import (
    CollectJob,
    DataJob,
    EvalJob,
    TrainJob,
    jobs,
    load_sweep,
    plan,
    replace_block,
    run_sweeps,
)
from snapflow.jobs.sweep.aggregate import TableResult
from snapflow.jobs.sweep.markdown import markdown_blocks, tables_markdown
from snapflow.jobs.sweep.planning import eval_job, train_job
from snapflow.jobs.sweep.results import write_results
from snapflow.policies.minivla import MiniVLAConfig
from snapflow.policies.mlp import MLPPolicyConfig
from snapflow.reporting.machine import versions
from snapflow.reporting.records import as_record
from snapflow.training.config import TEACHER_TRAINING
from snapflow.training.recipes import DEFAULT_RECIPE, RECIPES

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
) -> Path:
    path = directory / "tiny.toml"
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
episodes_per_task = 2
per_task = true
rows = [
  {{ label = "teacher 10-NFE", run = "teacher", mode = "teacher-10" }},
  {{ label = "SnapFlow 1-NFE", run = "snapflow", mode = "snapflow-1" }},{extra_rows}
]

[[tables]]
name = "nfe"
x_label = "NFE"
seeds = [0]
episodes_per_task = 2
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


def test_a_new_sweep_plans_collect_each_task_every_run_per_seed_and_one_evaluation_per_cell(tmp_path):
    planned = plan(load_sweep(write_config(tmp_path)))
    assert names(planned) == DATA | ALL_TRAINS | ALL_EVALS
    assert len(planned) == len(DATA) + len(ALL_TRAINS) + len(ALL_EVALS)
    position = {job: index for index, job in enumerate(planned)}
    assert all(position[dep] < position[job] for job in planned for dep in job.dependencies), "dependencies come first"


def test_changing_nothing_plans_nothing(tmp_path):
    assert finish(tmp_path) == set()


def test_changing_a_students_alpha_replans_exactly_that_student_and_its_evaluations(tmp_path):
    replanned = finish(tmp_path, snapflow_distill="{ target_steps = [2, 4], alpha = 0.7 }")
    assert replanned == {
        ("train", "snapflow", 0),
        ("train", "snapflow", 1),
        ("eval", "snapflow", 0, "snapflow-1"),
        ("eval", "snapflow", 1, "snapflow-1"),
    }


@pytest.mark.parametrize(
    "change",
    [
        {"teacher_train": TINY_TRAIN.replace("steps = 12", "steps = 13")},
        {"teacher_policy": TINY_POLICY.replace("num_layers = 1", "num_layers = 2")},
    ],
    ids=["train.steps", "policy.num_layers"],
)
def test_changing_a_teacher_replans_it_every_student_of_it_and_all_their_evaluations(tmp_path, change):
    assert finish(tmp_path, **change) == ALL_TRAINS | ALL_EVALS


def test_an_option_added_later_replans_only_the_runs_that_set_it(tmp_path):
    """Records of runs that leave an added option (here the weight average) at its default, as every record written
    before it existed does, stay done; a run that sets it trains again, with its evaluations."""
    assert finish(tmp_path, snapflow_train=TINY_TRAIN.replace(" }", ", ema_decay = 0.99 }")) == {
        ("train", "snapflow", 0),
        ("train", "snapflow", 1),
        ("eval", "snapflow", 0, "snapflow-1"),
        ("eval", "snapflow", 1, "snapflow-1"),
    }


def test_a_default_written_out_changes_nothing(tmp_path):
    """The settings are the resolved ones: giving a default explicitly is the same run."""
    assert finish(tmp_path, teacher_policy=TINY_POLICY.replace("}", ", chunk_length = 8 }")) == set()


def test_a_new_seed_plans_only_what_it_needs(tmp_path):
    assert finish(tmp_path, seeds="[0, 1, 2]") == {
        ("train", "teacher", 2),
        ("train", "snapflow", 2),
        ("eval", "teacher", 2, "teacher-10"),
        ("eval", "snapflow", 2, "snapflow-1"),
    }


def test_a_fresh_checkout_continues_from_the_ledger_committed_beside_the_results(tmp_path):
    """Each finished run and evaluation keeps a copy of its record under the results folder, to be committed; with
    the run folders gone, as on a fresh machine, nothing recorded there runs again, and a missing evaluation brings
    back only what it reads: its policy, that policy's teacher, and the data."""
    assert finish(tmp_path) == set()
    ledger = tmp_path / "results" / "records"
    recorded = {path.relative_to(ledger).as_posix() for path in ledger.rglob("*.json")}
    assert recorded == {f"{run}/seed-{seed}/job.json" for _, run, seed in ALL_TRAINS} | {
        f"evals/{run}/seed-{seed}/{mode}_nact4_eps2.json" for _, run, seed, mode in ALL_EVALS
    }
    config = load_sweep(write_config(tmp_path))
    shutil.rmtree(ledger / "teacher")  # a run recorded before its kind kept a copy gets one when the sweep is planned
    assert plan(config) == [] and {path.relative_to(ledger).as_posix() for path in ledger.rglob("*.json")} == recorded
    shutil.rmtree(tmp_path / "runs")
    assert plan(config) == []
    (ledger / "evals" / "snapflow" / "seed-1" / "snapflow-1_nact4_eps2.json").unlink()
    assert names(plan(config)) == DATA | {
        ("train", "teacher", 1),
        ("train", "snapflow", 1),
        ("eval", "snapflow", 1, "snapflow-1"),
    }


def test_job_settings_are_complete_and_keys_follow_the_dependencies(tmp_path):
    config = load_sweep(write_config(tmp_path))
    by_name = {next(iter(names([job]))): job for job in jobs(config)}
    teacher, student = by_name[("train", "teacher", 0)], by_name[("train", "snapflow", 1)]
    # every field, defaults included, but an option added later while it is off (see reporting.records)
    assert set(teacher.settings()["train"]) == set(asdict(TEACHER_TRAINING)) - {"ema_decay"}
    assert teacher.settings()["train"] == {**as_record(TEACHER_TRAINING), **teacher.settings()["train"]}
    assert teacher.settings()["policy"] == {"type": "minivla", **config.runs["teacher"].policy.to_dict()}
    assert student.settings()["train"]["learning_rate"] == RECIPES[DEFAULT_RECIPE].train.learning_rate
    assert student.settings()["distill"]["target_steps"] == (2, 4) and student.settings()["train"]["seed"] == 1
    assert student.teacher == by_name[("train", "teacher", 1)] and student.teacher.data == by_name[("data",)]
    assert student.data.parts == (by_name[("collect", "reach-v3")], by_name[("collect", "push-v3")])
    assert student.data.parts[1].settings() == {**student.data.settings(), "tasks": ("push-v3",)}
    assert len({job.key for job in jobs(config)}) == len(jobs(config)), "every job has its own key"
    evaluation = by_name[("eval", "snapflow", 1, "snapflow-1")]
    assert not evaluation.record_path.exists()
    write_record(evaluation, {"success": 1})
    assert read_record(evaluation) == {
        "config": evaluation.settings(),
        "dependencies": [student.key, student.data.key],
        "success": 1,
        "versions": versions(),  # what it was made under: the simulators among them
    }


def test_a_table_may_evaluate_other_initial_states_without_touching_the_first_ones_records(tmp_path):
    path = write_config(tmp_path)
    config = load_sweep(path)
    path.write_text(path.read_text().replace("per_task = true", "per_task = true\nfirst_variation = 10", 1))
    moved = load_sweep(path)
    assert [table.first_variation for table in moved.tables] == [10, 0]
    row = moved.tables[0].rows[0]
    first, later = eval_job(config, config.tables[0], row, 0), eval_job(moved, moved.tables[0], row, 0)
    # the first variations keep their settings and path (every committed record stays valid); the others are theirs
    assert "first_variation" not in first.settings() and first.path.name == "teacher-10_nact4_eps2.json"
    assert later.settings() == {**first.settings(), "first_variation": 10} and later.first_variation == 10
    assert later.path.name == "teacher-10_nact4_eps2_from10.json" and later.key != first.key
    path.write_text(path.read_text().replace("first_variation = 10", "first_variation = -1"))
    with pytest.raises(ValueError, match="first_variation must be an integer of at least 0, got -1"):
        load_sweep(path)


def test_a_table_may_evaluate_a_subset_of_the_tasks_without_touching_the_other_tables_records(tmp_path):
    path = write_config(tmp_path)
    config = load_sweep(path)
    path.write_text(path.read_text().replace("per_task = true", 'per_task = true\ntasks = "push-v3"', 1))
    narrowed = load_sweep(path)
    assert [table.tasks for table in narrowed.tables] == [("push-v3",), ()]
    assert narrowed.tasks_of(narrowed.tables[0]) == ("push-v3",) and narrowed.tasks_of(narrowed.tables[1]) == (
        "reach-v3",
        "push-v3",
    )
    row = narrowed.tables[0].rows[0]
    every, one = eval_job(config, config.tables[0], row, 0), eval_job(narrowed, narrowed.tables[0], row, 0)
    # every task keeps its settings and path (every committed record stays valid); a subset is a job of its own
    assert "tasks" not in every.settings() and every.path.name == "teacher-10_nact4_eps2.json"
    assert one.settings() == {**every.settings(), "tasks": ["push-v3"]} and one.task_names == ["push-v3"]
    assert re.fullmatch(r"teacher-10_nact4_eps2_1tasks-[0-9a-f]{8}\.json", one.path.name) and one.key != every.key
    # naming every task, in any order, is no subset: the table shares the others' evaluations
    path.write_text(path.read_text().replace('tasks = "push-v3"', 'tasks = ["push-v3", "reach-v3"]'))
    assert eval_job(load_sweep(path), load_sweep(path).tables[0], row, 0).path == every.path
    path.write_text(path.read_text().replace('tasks = ["push-v3", "reach-v3"]', 'tasks = "door-open-v3"'))
    with pytest.raises(ValueError, match=r"tasks \['door-open-v3'\] are not among the data's"):
        load_sweep(path)


def test_a_teacher_policy_table_picks_a_built_in_policy_sized_for_the_data(tmp_path):
    mlp = load_sweep(write_config(tmp_path, teacher_policy='{ type = "mlp", hidden_dim = 64 }')).runs["teacher"].policy
    assert mlp == MLPPolicyConfig(observation_dim=39 + 2, action_dim=4, chunk_length=8, hidden_dim=64)
    camera = (
        load_sweep(write_config(tmp_path, teacher_policy="{ use_image = true, state_dim = 4 }")).runs["teacher"].policy
    )
    assert camera == MiniVLAConfig(state_dim=4, action_dim=4, use_image=True)


def test_the_via_point_sweep_collects_on_its_own_benchmark():
    config = load_sweep(ROOT / "configs" / "sweeps" / "mt10-via-points.toml")
    assert config.data.env == "metaworld-via-points" and len(config.data.tasks) == 10


@pytest.mark.parametrize(
    ("name", "page"),
    [
        *(
            (name, "metaworld")
            for name in ("mt10-state", "mt10-camera", "mt10-via-points", "mt10-levers", "mt50-state")
        ),
        *((name, "libero") for name in ("libero-spatial", "libero-object")),
    ],
)
def test_the_committed_results_render_to_the_committed_markdown_byte_for_byte(monkeypatch, name, page):
    monkeypatch.chdir(ROOT)  # the command and links in the Markdown are the repository-relative paths
    config = load_sweep(f"configs/sweeps/{name}.toml")
    stored = json.loads((config.results_dir / "results.json").read_text())
    config = config.only(list(stored["tables"]))  # a table added to a config has no results until it is run
    results = {table.name: TableResult.from_dict(stored["tables"][table.name]) for table in config.tables}
    assert {name: result.to_dict() for name, result in results.items()} == stored["tables"]
    assert tables_markdown(config, results) == (config.results_dir / "tables.md").read_text()
    document = (ROOT / "docs" / "results" / f"{page}.md").read_text()  # the results page of the sweep's benchmark
    rewritten = document
    for key, body in markdown_blocks(config, results, Path("docs/results")).items():
        assert f"<!-- sweep:{key} -->" in document
        rewritten = replace_block(rewritten, key, body)
    assert rewritten == document


def test_one_table_plans_only_what_it_needs(tmp_path):
    config = load_sweep(write_config(tmp_path))
    assert names(plan(config.only(["nfe"]))) == DATA | {
        ("train", "teacher", 0),
        ("train", "meanflow", 0),
        ("eval", "teacher", 0, "naive-1"),
        ("eval", "teacher", 0, "teacher-2"),
        ("eval", "meanflow", 0, "snapflow-1"),
    }
    assert config.only(None) == config
    with pytest.raises(ValueError, match="no table 'headlines'; its tables are \\['headline', 'nfe'\\]"):
        config.only(["headlines"])


def test_rebuilding_some_tables_keeps_the_others_results_as_they_are(tmp_path, monkeypatch):
    """With no table rebuilt, every table is read back from results.json and written out byte for byte; one that
    results.json lacks (not run yet) is left out."""
    monkeypatch.chdir(ROOT)
    config = load_sweep("configs/sweeps/mt10-via-points.toml")
    copy = tmp_path / "results"
    copy.mkdir()
    for name in ("results.json", "tables.md"):
        (copy / name).write_bytes((config.results_dir / name).read_bytes())
    kept = replace(config, results_dir=copy)
    written = write_results(kept, tables=[])
    assert written["tables"] == json.loads((config.results_dir / "results.json").read_text())["tables"]
    assert (copy / "tables.md").read_text() == (config.results_dir / "tables.md").read_text()
    assert not list(copy.glob("*.png")), "no table was rebuilt, so no plot is redrawn"
    stored = json.loads((copy / "results.json").read_text())
    del stored["tables"]["targets"]
    (copy / "results.json").write_text(json.dumps(stored))
    written = write_results(kept, tables=[])  # a table that has not run yet is left out until it has
    assert list(written["tables"]) == list(stored["tables"])
    assert "### mt10-via-points/targets\n" not in (copy / "tables.md").read_text()
    assert "### mt10-via-points/headline\n" in (copy / "tables.md").read_text()


@pytest.mark.parametrize(
    "mistake, message",
    [
        ("[data]\nepisodes = 3\n", "unknown key(s) ['episodes']"),
        ("[data]\nvia_points = true\n", "unknown key(s) ['via_points']"),
        ('[data]\nenv = "mujoco"\n', "unknown environment 'mujoco'"),
        ("[runs.teacher]\npolicy = { width = 3 }\n", "unknown key(s) ['width']"),
        ('[runs.teacher]\npolicy = { type = "mlp", prefix_width = 3 }\n', "unknown key(s) ['prefix_width']"),
        ('[runs.teacher]\npolicy = { type = "transformer" }\n', "unknown policy 'transformer'"),
        ("[runs.teacher]\npolicy = { num_layers = 0 }\n", "MiniVLAConfig.num_layers must be at least 1"),
        ('[runs.student]\nteacher = "nobody"\n', "teacher 'nobody' is not a teacher run"),
        (
            '[runs.teacher]\nseeds = [0]\n[runs.student]\nteacher = "teacher"\nseeds = [1]\n',
            "seeds [1] have no 'teacher' teacher",
        ),
        ("[runs.teacher]\ntrain = { steps = 0 }\n", "TrainConfig.steps must be at least 1"),
        (
            '[runs.teacher]\n[runs.student]\nteacher = "teacher"\ndistill = { method = "dance" }\n',
            "unknown distillation method 'dance'",
        ),
        (
            '[runs.teacher]\n[runs.student]\nteacher = "teacher"\ndistill = { target = "bootstrap", target_steps = 6 }\n',
            "power of two",
        ),
        (
            '[runs.teacher]\n[[tables]]\nname = "t"\nrows = [{ label = "x", run = "ghost", mode = "naive" }]\n',
            "unknown run 'ghost'",
        ),
        (
            '[runs.teacher]\n[[tables]]\nname = "t"\nrows = [{ label = "x", run = "teacher", mode = "fast" }]\n',
            "unknown sampling mode 'fast'",
        ),
        (
            '[runs.teacher]\n[[tables]]\nname = "t"\nseeds = [5]\nrows = [{ label = "x", run = "teacher", mode = "naive" }]\n',
            "needs seeds [5]",
        ),
        ('[data]\ntasks = ["fly-v3"]\n', "unknown metaworld task(s) ['fly-v3']"),
        ('seeds = "all"\n', "seeds must be a non-empty list of integers"),
        ('[runs.teacher]\ncommit_checkpoint = "yes"\n', "[runs.teacher]: commit_checkpoint must be true or false"),
        ('[data]\nextra_cameras = "image2"\n', "[data] extra_cameras must be a list of camera names"),
        ('[data]\nextra_cameras = ["wrist"]\n', "[data] extra_cameras: metaworld has no camera(s) ['wrist']"),
        ('[data]\naction_noise = "some"\n', "[data] action_noise must be a number of at least 0, got 'some'"),
        ("[data]\naction_noise = -0.2\n", "[data] action_noise must be a number of at least 0, got -0.2"),
        ("[runs.teacher\n", "not valid TOML"),
        ("runs = 3\n", "[runs]: expected a table"),
        ('[runs.teacher]\n[[tables]]\nname = "t"\nrows = 3\n', "rows must be a list"),
        ('[runs.teacher]\n[[tables]]\nname = "t"\nrows = [3]\n', "row: expected a table"),
        (
            '[runs.teacher]\n[[tables]]\nname = "t"\nreference = "y"\nrows = [{ label = "x", run = "teacher", mode = "naive" }]\n',
            "reference 'y' is not one of its rows",
        ),
        ("[data]\nepisodes_per_task = 0\n", "[data]: episodes_per_task must be an integer of at least 1, got 0"),
        (
            '[runs.teacher]\n[[tables]]\nname = "t"\nepisodes_per_task = 0\nrows = [{ label = "x", run = "teacher", mode = "naive" }]\n',
            "episodes_per_task must be an integer of at least 1, got 0",
        ),
        (
            '[runs.teacher]\n[[tables]]\nname = "t"\nrows = [{ label = "x", run = "teacher", mode = "naive", n_act = 0 }]\n',
            "row 'x': n_act must be an integer of at least 1, got 0",
        ),
    ],
)
def test_a_bad_sweep_config_is_refused_with_its_section_named(tmp_path, capsys, mistake, message):
    path = tmp_path / "bad.toml"
    body = 'name = "bad"\n' + mistake
    if "[runs." not in mistake and "runs =" not in mistake:
        body += "[runs.teacher]\n"
    if "[[tables]]" not in mistake:
        body += '[[tables]]\nname = "t"\nrows = []\n'
    path.write_text(body)
    assert main(["sweep", str(path), "--report-only", "--no-progress"]) == 2
    error = capsys.readouterr().err
    assert message in error and "Traceback" not in error


def _reader(directory: Path, rows: str, data: str = 'env = "libero"\ntasks = "libero_object"\n') -> Path:
    """A sweep whose table's rows are given, in ``directory`` beside its outputs."""
    path = directory / "reader.toml"
    path.write_text(
        f'name = "reader"\noutput_dir = "{(directory / "runs").as_posix()}"\n'
        f'results_dir = "{(directory / "results").as_posix()}"\n[data]\n{data}[runs.teacher]\n'
        f'[[tables]]\nname = "t"\nper_task = true\nepisodes_per_task = 10\nrows = [{rows}]\n'
    )
    return path


def test_a_row_reads_another_sweeps_evaluation_on_the_same_tasks_paired_and_never_runs_it(tmp_path, monkeypatch):
    """Two rows read from LIBERO-Object's committed records give that sweep's own rows (successes, per task, the
    paired difference), say where they came from, and plan no job of that sweep."""
    monkeypatch.chdir(ROOT)
    other = (ROOT / "configs" / "sweeps" / "libero-object.toml").as_posix()
    config = load_sweep(
        _reader(
            tmp_path,
            f'{{ label = "teacher", sweep = "{other}", run = "teacher", mode = "teacher-10" }}, '
            f'{{ label = "naive", sweep = "{other}", run = "teacher", mode = "naive" }}',
        )
    )
    assert plan(config) == [] and not [job for job in jobs(config) if isinstance(job, (TrainJob, EvalJob))]
    rows = write_results(config)["tables"]["t"]["rows"]
    committed = json.loads((ROOT / "docs/results/sweeps/libero-object/results.json").read_text())["tables"]
    expected = {row["label"]: row for row in committed["noise-free"]["rows"]}
    for row, label in zip(rows, ["teacher 10-NFE", "naive 1-NFE"], strict=True):
        assert row["sweep"] == "libero-object" and row["run"] == "teacher"
        for key in ("successes", "episodes", "per_task", "success_interval", "training_s", "offline"):
            assert row[key] == expected[label][key], key
    assert rows[1]["difference"]["mean"] == expected["naive 1-NFE"]["difference"]["mean"] == -2.0
    assert "naive (sweep libero-object, run teacher)" in (tmp_path / "results" / "tables.md").read_text()


def test_a_row_that_reads_another_sweep_is_refused_on_other_tasks_an_unknown_run_or_a_cycle(tmp_path, capsys):
    other = tmp_path / "other"
    other.mkdir()
    _reader(other, '{ label = "x", sweep = "../reader.toml", run = "teacher", mode = "naive" }')
    for rows, data, message in [
        ('{ label = "x", sweep = "nowhere.toml", run = "teacher", mode = "naive" }', None, "no sweep config at"),
        ('{ label = "x", sweep = "reader.toml", run = "teacher", mode = "naive" }', None, "cannot read each other"),
        ('{ label = "x", sweep = "other/reader.toml", run = "teacher", mode = "naive" }', None, "cannot read each"),
        ('{ label = "x", sweep = 3, run = "teacher", mode = "naive" }', None, "sweep must be the path of a sweep"),
        (
            f'{{ label = "x", sweep = "{(ROOT / "configs/sweeps/libero-object.toml").as_posix()}", run = "ghost", '
            'mode = "naive" }',
            None,
            "unknown run 'ghost' of sweep 'libero-object'",
        ),
        (
            f'{{ label = "x", sweep = "{(ROOT / "configs/sweeps/libero-object.toml").as_posix()}", run = "teacher", '
            'mode = "naive" }',
            'env = "libero"\ntasks = "libero_spatial"\n',
            "a row pairs with the table's only on the same benchmark and tasks",
        ),
    ]:
        path = _reader(tmp_path, rows, *([data] if data else []))
        assert main(["sweep", str(path), "--report-only", "--no-progress"]) == 2
        error = capsys.readouterr().err
        assert message in error and "Traceback" not in error, (message, error)


def test_replace_block_appends_a_missing_block_and_replaces_an_existing_one():
    document = "# R\n\ntext\n"
    once = replace_block(document, "a/b", "first")
    assert once == "# R\n\ntext\n\n<!-- sweep:a/b -->\nfirst\n<!-- /sweep:a/b -->\n"
    assert replace_block(once, "a/b", "second") == once.replace("first", "second")
    assert replace_block(once, "a/b", "x\\1").count("x\\1") == 1  # bodies are literal text, not regex templates


def test_report_only_on_an_unfinished_sweep_names_what_is_missing(tmp_path, capsys):
    assert main(["sweep", str(write_config(tmp_path)), "--report-only", "--no-progress"]) == 2
    error = capsys.readouterr().err
    assert "table 'headline' is incomplete" in error
    assert error.rstrip().endswith("first"), error  # the message's own end, no file name of None after it


def test_report_only_refuses_evaluations_made_with_other_settings(tmp_path, capsys):
    finish(tmp_path)
    write_config(tmp_path, teacher_train=TINY_TRAIN.replace("steps = 12", "steps = 13"))
    assert main(["sweep", str(tmp_path / "tiny.toml"), "--report-only", "--no-progress"]) == 2
    assert "made with other settings" in capsys.readouterr().err


def test_the_runner_has_nothing_to_do_when_every_job_is_done(tmp_path):
    finish(tmp_path)
    assert run_jobs(jobs(load_sweep(tmp_path / "tiny.toml")), workers=2, progress=False) == {}


@dataclass(frozen=True)
class LogJob(Job):
    """Appends a line to its log; ``fail`` (not a setting) makes it fail after writing, as an interrupted run."""

    kind: ClassVar[str] = "log"
    directory: Path
    value: int
    fail: bool = False

    def settings(self) -> dict[str, Any]:
        return {"value": self.value}

    @property
    def record_path(self) -> Path:
        return self.directory / "job.json"

    @property
    def outputs(self) -> tuple[Path, ...]:
        return (self.directory,)

    def run(self) -> dict[str, Any]:
        with open(self.directory / "log.txt", "a") as log:
            log.write(f"{self.value}\n")
        if self.fail:
            raise RuntimeError("the job failed on purpose")
        lines = len((self.directory / "log.txt").read_text().splitlines())
        return {"lines": lines, "process": os.getpid(), "threads": torch.get_num_threads()}

    def describe(self) -> str:
        return f"log {self.value}"


@dataclass(frozen=True)
class StageJob(LogJob):
    """A log job that reads others' outputs."""

    needs: tuple[Job, ...] = ()

    @property
    def dependencies(self) -> tuple[Job, ...]:
        return self.needs


def test_a_teachers_evaluation_runs_before_its_students_training(tmp_path):
    teacher = StageJob(tmp_path / "teacher", 0)
    student = StageJob(tmp_path / "student", 1, needs=(teacher,))
    student_eval = StageJob(tmp_path / "student-eval", 2, needs=(student,))
    teacher_eval = StageJob(tmp_path / "teacher-eval", 3, needs=(teacher,))
    assert to_run([student_eval, teacher_eval]) == [teacher, teacher_eval, student, student_eval]


@pytest.mark.slow
def test_a_ready_evaluation_runs_before_a_teacher_that_waits_at_a_lower_depth(tmp_path):
    """One worker, two teachers and their evaluations: to_run's order trains both teachers first (depth), but once
    the first is trained its evaluation, ready and needed by nothing, runs before the second teacher starts."""
    first, second = StageJob(tmp_path / "first", 0), StageJob(tmp_path / "second", 1)
    first_eval = StageJob(tmp_path / "first-eval", 2, needs=(first,))
    second_eval = StageJob(tmp_path / "second-eval", 3, needs=(second,))
    assert to_run([first_eval, second_eval]) == [first, second, first_eval, second_eval]
    finished = list(run_jobs([first_eval, second_eval], workers=1, progress=False))
    assert finished == ["log 0", "log 2", "log 1", "log 3"]


@pytest.mark.slow
def test_the_runner_continues_an_interrupted_job_and_restarts_a_stale_one(tmp_path):
    directory = tmp_path / "job"
    with pytest.raises(RuntimeError, match="failed on purpose"):  # a failed job stops the run with its own error
        run_jobs([LogJob(directory, 1, fail=True)], progress=False)
    assert not is_done(LogJob(directory, 1))
    assert set(run_jobs([LogJob(directory, 1)], progress=False)) == {"log 1"}
    record = read_record(LogJob(directory, 1))
    assert (record["config"], record["lines"]) == ({"value": 1}, 2), "same settings: its outputs were kept"
    assert run_jobs([LogJob(directory, 1)], progress=False) == {}
    run_jobs([LogJob(directory, 2)], progress=False)
    assert read_record(LogJob(directory, 2))["lines"] == 1, "other settings: its old outputs were cleared first"
    assert not is_done(LogJob(directory, 1))


@dataclass(frozen=True)
class KilledJob(LogJob):
    """A log job whose worker is killed as it runs, as the system kills one out of memory."""

    def run(self) -> dict[str, Any]:
        super().run()
        os.kill(os.getpid(), signal.SIGKILL)
        return {}


def test_a_killed_worker_stops_the_run_naming_its_job_and_the_same_command_goes_on(tmp_path):
    directory = tmp_path / "job"
    with pytest.raises(SnapflowError, match=r"the worker running log 1 died \(killed, or out of memory\)"):
        run_jobs([KilledJob(directory, 1)], progress=False)
    assert not is_done(LogJob(directory, 1))
    run_jobs([LogJob(directory, 1)], progress=False)
    assert read_record(LogJob(directory, 1))["lines"] == 2, "its pending run's outputs were kept and went on"


@pytest.mark.slow
def test_every_job_runs_in_a_fresh_process_so_its_memory_goes_with_it(tmp_path):
    jobs = [LogJob(tmp_path / f"job-{value}", value) for value in range(3)]
    run_jobs(jobs, workers=1, progress=False)
    processes = {read_record(job)["process"] for job in jobs}
    assert len(processes) == 3 and os.getpid() not in processes
    assert {read_record(job)["threads"] for job in jobs} == {os.cpu_count()}, "one worker: every core's thread"


@pytest.mark.slow
def test_a_job_runs_on_the_threads_asked_for_where_other_programs_share_the_cores(tmp_path):
    job = LogJob(tmp_path / "job", 0)
    run_jobs([job], workers=1, progress=False, threads=1)
    assert read_record(job)["threads"] == 1


# ~150 s on CI's two cores: the sweep's one end-to-end run on a simulator (collection, teachers, students, every
# table) then its cache and rerun rules on the same folders; each part is at its smallest.
@pytest.mark.slow
def test_a_sweep_runs_caches_reruns_a_changed_student_and_writes_its_tables_into_the_document(tmp_path, capsys):
    config_path = write_config(tmp_path)
    document = tmp_path / "RESULTS.md"
    document.write_text(
        "# Results\n\nProse before.\n\n<!-- sweep:tiny/headline -->\nold table\n<!-- /sweep:tiny/headline -->\n\nProse after.\n"
    )
    assert main(["sweep", str(config_path), "--workers", "2", "--document", str(document), "--no-progress"]) == 0
    results = json.loads((tmp_path / "results" / "results.json").read_text())
    headline = results["tables"]["headline"]["rows"]
    assert [row["label"] for row in headline] == ["teacher 10-NFE", "SnapFlow 1-NFE"]
    for row in headline:
        assert row["episodes"] == 2 * 2 * 2  # tasks x episodes per task x seeds
        assert len(row["success_per_seed"]) == 2 and row["success_mean"] == pytest.approx(
            sum(row["success_per_seed"]) / 2
        )
        assert 0 <= row["offline"]["mse"] and -1 <= row["offline"]["cosine"] <= 1
        assert all(seconds > 0 for seconds in row["training_s"])
    teacher_row, student_row = headline
    assert "difference" not in teacher_row, "the first row is the reference"
    assert student_row["difference"]["reference"] == "teacher 10-NFE" and student_row["difference"]["cells"] == 4
    for row in headline:  # the interval brackets the pooled rate
        low, high = row["success_interval"]
        assert 0 <= low <= 100 * row["successes"] / row["episodes"] <= high <= 100
    cells = {  # (seed, task) success of each row from the cached records: the paired difference is their mean
        run: [
            100
            * json.loads((tmp_path / "runs" / "evals" / run / f"seed-{seed}" / name).read_text())["success"][task][
                "success_rate"
            ]
            for seed in (0, 1)
            for task in load_sweep(config_path).data.tasks
        ]
        for run, name in (("teacher", "teacher-10_nact4_eps2.json"), ("snapflow", "snapflow-1_nact4_eps2.json"))
    }
    assert student_row["difference"]["mean"] == pytest.approx(sum(cells["snapflow"]) / 4 - sum(cells["teacher"]) / 4)
    for seed in (0, 1):  # the table's numbers are the cached evaluation records'
        cached = json.loads(
            (tmp_path / "runs" / "evals" / "teacher" / f"seed-{seed}" / "teacher-10_nact4_eps2.json").read_text()
        )
        assert headline[0]["success_per_seed"][seed] == pytest.approx(100 * cached["success"]["mean"]["success_rate"])
        # its episodes, logged as they finished (what an interrupted evaluation goes on from)
        log = (
            tmp_path
            / "runs"
            / "evals"
            / "teacher"
            / f"seed-{seed}"
            / "teacher-10_nact4_eps2.episodes"
            / "00-teacher-10.jsonl"
        )
        waves = [json.loads(line)["episodes"] for line in log.read_text().splitlines()[1:]]
        assert sum(episode["success"] for wave in waves for episode in wave) == cached["success"]["mean"]["successes"]
    for name in ("headline.png", "nfe.png", "tables.md"):
        assert (tmp_path / "results" / name).stat().st_size > 0

    text = document.read_text()
    assert "Prose before." in text and "Prose after." in text and "old table" not in text
    assert "| SnapFlow 1-NFE | 1 | 4 |" in text and "<!-- sweep:tiny/nfe -->" in text
    assert "](results/headline.png)" in text and "seeds 0, 1" in text
    assert plan(load_sweep(config_path)) == []  # everything is cached: a second run does nothing

    runs = tmp_path / "runs"
    for run in ("teacher", "meanflow"):
        (runs / run / "seed-0" / "left-over.txt").write_text("made with the old settings")
    records = {path: path.stat().st_mtime_ns for path in runs.rglob("*.json")}
    write_config(tmp_path, meanflow_distill='{ method = "meanflow", alpha = 0.7 }')
    times = run_sweeps([load_sweep(config_path)], workers=2, progress=False)
    assert set(times) == {"tiny: train meanflow seed 0", "tiny: evaluate meanflow seed 0 (snapflow-1; n_act 4)"}
    rewritten = {
        path.relative_to(runs).as_posix()
        for path, stamp in records.items()
        if not path.is_file() or path.stat().st_mtime_ns != stamp
    }
    assert {path for path in rewritten if not path.startswith("meanflow/seed-0/")} == {
        "evals/meanflow/seed-0/snapflow-1_nact4_eps2.json"
    }
    assert "meanflow/seed-0/job.json" in rewritten
    assert not (runs / "meanflow" / "seed-0" / "left-over.txt").exists(), "a stale run starts from an empty folder"
    assert (runs / "teacher" / "seed-0" / "left-over.txt").exists(), "the teacher did not run again"
    assert read_record(train_job(load_sweep(config_path), "meanflow", 0))["config"]["distill"]["alpha"] == 0.7

    # a fresh checkout: the run folders gone, the ledger committed beside the results kept
    config = load_sweep(config_path)
    tables = write_results(config)["tables"]
    shutil.rmtree(runs)
    assert plan(config) == [], "every result is recorded: nothing runs again"
    assert write_results(config)["tables"] == tables, "the tables come back from the ledger alone"


def test_a_sweep_into_an_output_dir_another_process_holds_is_refused_before_any_job(tmp_path, capsys):
    from tests.locking import held_by_another_process

    runs = tmp_path / "runs"
    with held_by_another_process(runs, "snapflow sweep") as holder:
        assert main(["sweep", str(write_config(tmp_path)), "--no-progress"]) == 2
    assert capsys.readouterr().err.splitlines() == [
        f"snapflow sweep: error: {runs} is in use by another snapflow command (pid {holder.pid}, snapflow sweep); "
        "wait for it to finish or give the sweep another output_dir"
    ]
    assert [path.name for path in runs.iterdir()] == [".snapflow.lock"], "no job started"


# ~125 s on CI's two cores: a sweep from a real collection, then on a "fresh machine" a new evaluation of its kept
# teacher, and a teacher interrupted and continued there beside one never interrupted, whose weights it must end with.
@pytest.mark.slow
def test_a_fresh_machine_evaluates_a_kept_policy_and_continues_a_kept_unfinished_run(tmp_path, monkeypatch, capfd):
    """commit_checkpoint: a finished run's policy, kept beside its ledger record, comes back on a fresh machine for a
    new evaluation of it (no training again); a run interrupted there continues from its kept checkpoint and ends
    with the weights of a run never interrupted."""
    from snapflow.jobs.runner import _start
    from snapflow.training import trainer
    from snapflow.training.stages import train_teacher

    config = load_sweep(write_config(tmp_path, seeds="[0]", commit_checkpoint=True)).only(["headline"])
    run_sweeps([config], progress=False)
    kept = tmp_path / "results" / "records" / "teacher" / "seed-0" / "checkpoint"
    state = json.loads((kept / "kept.json").read_text())
    assert state["finished"] and state["checkpoint"] == "step_0000012"
    assert sorted(path.name for path in (kept / "step_0000012").iterdir()) == ["policy.json", "policy.safetensors"]
    assert [path.name for path in kept.glob("step_*")] == ["step_0000012"], "only the last checkpoint is kept"
    assert not (tmp_path / "results" / "records" / "snapflow" / "seed-0" / "checkpoint").exists(), "the teacher's alone"

    shutil.rmtree(tmp_path / "runs")  # a fresh machine: the ledger and the kept checkpoints committed, nothing else
    extra = '\n  { label = "teacher 2-NFE", run = "teacher", mode = "teacher-2" },'
    config = load_sweep(write_config(tmp_path, seeds="[0]", extra_rows=extra, commit_checkpoint=True)).only(
        ["headline"]
    )
    assert names(plan(config)) == DATA | {("eval", "teacher", 0, "teacher-2")}, "the teacher is not trained again"
    teacher = train_job(config, "teacher", 0)
    assert (teacher.directory / "checkpoints" / "step_0000012" / "policy.safetensors").read_bytes() == (
        kept / "step_0000012" / "policy.safetensors"
    ).read_bytes()
    assert set(run_sweeps([config], progress=False)) == {
        "tiny: collect reach-v3",
        "tiny: collect push-v3",
        "tiny: demonstrations of 2 tasks",
        "tiny: evaluate teacher seed 0 (teacher-2; n_act 4)",
    }

    # the same teacher with other settings, interrupted after its first checkpoint (step 6 of 12) on one machine
    more_steps = TINY_TRAIN.replace("steps = 12", "steps = 13")
    teacher = train_job(
        load_sweep(write_config(tmp_path, seeds="[0]", teacher_train=more_steps, commit_checkpoint=True)), "teacher", 0
    )
    steps = {"taken": 0}
    step = trainer.train_step

    def interrupted_step(*args, **kwargs):
        steps["taken"] += 1
        if steps["taken"] == 8:
            raise KeyboardInterrupt("the machine went away")
        return step(*args, **kwargs)

    monkeypatch.setattr(trainer, "train_step", interrupted_step)
    _start(teacher)
    with pytest.raises(KeyboardInterrupt):
        teacher.run()
    monkeypatch.setattr(trainer, "train_step", step)
    state = json.loads((kept / "kept.json").read_text())
    assert (state["finished"], state["checkpoint"]) == (False, "step_0000006")
    assert (kept / "step_0000006" / "optimizer.safetensors").is_file(), "all that resuming reads is kept"
    assert not teacher.restore_outputs(), "an unfinished run's checkpoint is not a finished policy"

    shutil.rmtree(teacher.directory)  # on a fresh machine it continues at step 6
    capfd.readouterr()
    run_jobs([teacher], progress=False)
    assert f"resuming {teacher.directory} at step 6" in capfd.readouterr().out
    history = json.loads((teacher.directory / "history.json").read_text())
    assert history["step"] == 13 and json.loads((kept / "kept.json").read_text())["finished"]
    never_interrupted = tmp_path / "never-interrupted"
    train_teacher(teacher.data.directory, never_interrupted, teacher.policy, teacher.train, progress=False)
    last = "checkpoints/step_0000013/policy.safetensors"
    assert (teacher.directory / last).read_bytes() == (never_interrupted / last).read_bytes()


def test_a_data_section_that_names_its_cameras_changes_its_key_and_one_that_does_not_keeps_the_committed_records():
    """The LIBERO-Spatial teachers, recorded before [data] could name cameras, are still recorded (their key holds);
    a sweep that stores fewer cameras is other demonstrations (another key: collected again, its runs trained again)."""
    config = load_sweep(ROOT / "configs" / "sweeps" / "libero-spatial.toml")
    assert config.data.extra_cameras is None
    assert all(is_recorded(train_job(config, "teacher", seed)) for seed in (0, 2))
    main_camera_only = replace(config, data=replace(config.data, extra_cameras=()))
    assert train_job(main_camera_only, "teacher", 0).data.key != train_job(config, "teacher", 0).data.key


def test_collection_noise_in_the_data_section_is_other_demonstrations_and_its_absence_keeps_the_committed_records(
    tmp_path,
):
    """``action_noise`` came after the LIBERO records: left at 0 it leaves their key alone; set, it is other data,
    every task's collection job carries it."""
    config = load_sweep(ROOT / "configs" / "sweeps" / "libero-spatial.toml")
    assert config.data.action_noise == 0.0 and is_recorded(train_job(config, "teacher", 0))
    path = tmp_path / "noisy.toml"
    path.write_text(
        'name = "noisy"\n[data]\ntasks = ["reach-v3"]\naction_noise = 0.25\n[runs.teacher]\n'
        '[[tables]]\nname = "t"\nrows = []\n'
    )
    noisy = load_sweep(path)
    plain = replace(noisy, data=replace(noisy.data, action_noise=0.0))
    assert noisy.data.action_noise == 0.25
    assert train_job(noisy, "teacher", 0).data.key != train_job(plain, "teacher", 0).data.key
    assert [part.data.action_noise for part in train_job(noisy, "teacher", 0).data.parts] == [0.25]
