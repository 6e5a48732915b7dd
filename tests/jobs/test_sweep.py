"""`snapflow sweep`'s plan: the cache rule keyed by each job's full settings (fast: finished jobs are records written
the way the runner writes them), the ledger a fresh checkout continues from, and the keys the committed records hold."""

from __future__ import annotations

import re
import shutil
from dataclasses import asdict, replace

import pytest

from snapflow.cli import main
from snapflow.jobs.runner import is_recorded, read_record, run_jobs, write_record
from snapflow.jobs.sweep import jobs, load_sweep, plan
from snapflow.jobs.sweep.planning import eval_job, train_job
from snapflow.policies.minivla import MiniVLAConfig
from snapflow.policies.mlp import MLPPolicyConfig
from snapflow.reporting.machine import versions
from snapflow.reporting.records import as_record
from snapflow.training.config import TEACHER_TRAINING
from snapflow.training.recipes import DEFAULT_RECIPE, RECIPES
from tests.jobs.tiny_sweep import (
    ALL_EVALS,
    ALL_TRAINS,
    DATA,
    ROOT,
    TINY_POLICY,
    TINY_TRAIN,
    finish,
    names,
    write_config,
)


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


def test_a_collection_stopped_after_its_files_before_its_record_is_recorded_by_the_same_command(tmp_path):
    """A collection job whose demonstrations were saved whole but whose record was not (the run stopped in between)
    takes them as they are when the same command runs it again: they were collected with its settings."""
    from snapflow.jobs.runner import _start
    from snapflow.jobs.sweep import CollectJob
    from tests.training.fixtures import synthetic_demonstrations

    job = next(job for job in jobs(load_sweep(write_config(tmp_path))) if isinstance(job, CollectJob))
    _start(job)  # what the interrupted run noted: its settings, pending
    synthetic_demonstrations().save(job.directory)
    saved = {path.name: path.read_bytes() for path in job.directory.iterdir() if path.is_file()}
    assert job.run() == {}, "no collection again (it would refuse a folder that holds demonstrations)"
    assert {path.name: path.read_bytes() for path in job.directory.iterdir() if path.is_file()} == saved


def test_job_settings_are_complete_and_keys_follow_the_dependencies(tmp_path):
    config = load_sweep(write_config(tmp_path))
    by_name = {next(iter(names([job]))): job for job in jobs(config)}
    teacher, student = by_name[("train", "teacher", 0)], by_name[("train", "snapflow", 1)]
    # every field, defaults included, but an option added later while it is off (see reporting.records)
    assert set(teacher.settings()["train"]) == set(asdict(TEACHER_TRAINING)) - {"ema_decay", "time_distribution"}
    assert teacher.settings()["train"] == {**as_record(TEACHER_TRAINING), **teacher.settings()["train"]}
    assert teacher.settings()["policy"] == {"type": "minivla", **config.runs["teacher"].spec.to_dict()}
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


def test_a_table_may_cut_its_episodes_short_into_records_of_its_own(tmp_path):
    """A cut table (a quick check of a sweep) keeps the uncut evaluations' settings and paths, so every committed
    record stays valid; its own cells are other jobs, whose record says the cut."""
    config = load_sweep(write_config(tmp_path))
    cut = load_sweep(write_config(tmp_path, max_episode_steps=20))
    assert [table.max_episode_steps for table in config.tables + cut.tables] == [None, None, 20, 20]
    row = cut.tables[0].rows[0]
    full, short = eval_job(config, config.tables[0], row, 0), eval_job(cut, cut.tables[0], row, 0)
    assert "max_episode_steps" not in full.settings() and full.path.name == "teacher-10_nact4_eps2.json"
    assert short.settings() == {**full.settings(), "max_episode_steps": 20} and short.max_episode_steps == 20
    assert short.path.name == "teacher-10_nact4_eps2_cut20.json" and short.key != full.key
    assert short.policy == full.policy, "the same trained policy"
    with pytest.raises(ValueError, match="max_episode_steps must be an integer of at least 1, got 0"):
        load_sweep(write_config(tmp_path, max_episode_steps=0))


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
    mlp = load_sweep(write_config(tmp_path, teacher_policy='{ type = "mlp", hidden_dim = 64 }')).runs["teacher"].spec
    assert mlp == MLPPolicyConfig(observation_dim=39 + 2, action_dim=4, chunk_length=8, hidden_dim=64)
    camera = (
        load_sweep(write_config(tmp_path, teacher_policy="{ use_image = true, state_dim = 4 }")).runs["teacher"].spec
    )
    assert camera == MiniVLAConfig(state_dim=4, action_dim=4, use_image=True)


def test_the_via_point_sweep_collects_on_its_own_benchmark():
    config = load_sweep(ROOT / "configs" / "sweeps" / "mt10-via-points.toml")
    assert config.data.env == "metaworld-via-points" and len(config.data.tasks) == 10


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
