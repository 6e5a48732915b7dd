"""A sweep of LeRobot runs: a SmolVLA teacher trained from scratch on the sweep's demonstrations written as a
LeRobotDataset, its students distilled by snapflow's trainer and by LeRobot's ``lerobot-train``, every row evaluated
by snapflow's evaluator (planning: fast; a tiny sweep run for real: slow, LeRobot >= 0.5)."""

from __future__ import annotations

import json
import shutil
import time
from pathlib import Path

import pytest

from snapflow.adapters.lerobot_types import PLUGIN_LEROBOT, lerobot_loads_plugins
from snapflow.cli import main
from snapflow.jobs.sweep import TrainJob, jobs, load_sweep
from snapflow.jobs.sweep.data_jobs import LeRobotDatasetJob
from snapflow.jobs.sweep.eval_jobs import EvalJob
from snapflow.jobs.sweep.planning import train_job
from snapflow.policies.loaded import CheckpointError
from snapflow.sources import open_policy

TINY_TRAIN = "{ steps = 4, batch_size = 4, warmup_steps = 1, log_every = 2, validate_every = 4, checkpoint_every = 2 }"


def write_config(directory: Path, runs: str = "", rows: str = "") -> Path:
    path = directory / "smolvla.toml"
    path.write_text(f"""
name = "smolvla"
seeds = [0]
output_dir = "{(directory / "runs").as_posix()}"
results_dir = "{(directory / "results").as_posix()}"

[data]
tasks = ["reach-v3", "button-press-topdown-v3"]
episodes_per_task = 3
image_size = 32

[runs.teacher]
lerobot = {{ smolvlm = "tiny", image_size = 32, chunk_size = 4, n_action_steps = 2 }}
train = {TINY_TRAIN}
commit_checkpoint = true
[runs.distilled]
teacher = "teacher"
train = {TINY_TRAIN}
[runs.lerobot-train]
teacher = "teacher"
trainer = "lerobot-train"
train = {{ steps = 4, batch_size = 4, warmup_steps = 1, log_every = 1, checkpoint_every = 2 }}
commit_checkpoint = true
{runs}
[[tables]]
name = "headline"
episodes_per_task = 1
max_episode_steps = 20
per_task = true
rows = [
  {{ label = "teacher 10-NFE", run = "teacher", mode = "teacher-10" }},
  {{ label = "naive 1-NFE", run = "teacher", mode = "naive" }},
  {{ label = "SnapFlow 1-NFE, lerobot-train", run = "lerobot-train", mode = "snapflow-1" }},
  {{ label = "SnapFlow 1-NFE, snapflow distill", run = "distilled", mode = "snapflow-1" }},{rows}
]
""")
    return path


def test_a_lerobot_teacher_and_its_students_train_on_the_demonstrations_written_once_as_a_lerobot_dataset(tmp_path):
    config = load_sweep(write_config(tmp_path))
    planned = jobs(config)
    datasets = [job for job in planned if isinstance(job, LeRobotDatasetJob)]
    assert len(datasets) == 1 and datasets[0].directory == tmp_path / "runs" / "lerobot"
    trains = {job.run_name: job for job in planned if isinstance(job, TrainJob)}
    assert all(job.dataset == datasets[0] and datasets[0] in job.dependencies for job in trains.values())
    teacher, distilled, by_lerobot = trains["teacher"], trains["distilled"], trains["lerobot-train"]
    assert planned.index(datasets[0]) < planned.index(teacher) < planned.index(by_lerobot)
    assert teacher.settings()["lerobot"] == {
        "policy_type": "smolvla",
        "smolvlm": "tiny",
        "image_size": 32,
        "chunk_size": 4,
        "n_action_steps": 2,
    }
    # where each trained policy is, as open_policy reads it
    assert teacher.policy_path == teacher.directory / "lerobot_policy"
    assert distilled.policy_path == distilled.directory / "lerobot_policy"
    assert by_lerobot.policy_path == by_lerobot.directory / "lerobot-train/checkpoints/last/pretrained_model"
    # the trainer is part of a student's key where it is LeRobot's; snapflow's own keeps the records made before it
    assert by_lerobot.settings()["trainer"] == "lerobot-train" and "trainer" not in distilled.settings()
    assert train_job(config, "lerobot-train", 0).key != train_job(config, "distilled", 0).key


@pytest.mark.parametrize("run", ["lerobot-train", "teacher"])
def test_a_finished_lerobot_runs_policy_folder_is_kept_and_put_back_on_a_fresh_machine(tmp_path, run):
    """``commit_checkpoint`` on a LeRobot run (a lerobot-train student, a teacher trained from scratch) keeps its
    finished policy folder beside its ledger record; a machine without the run folder gets the folder back where
    evaluations and students read it (``restore_outputs``)."""
    job = train_job(load_sweep(write_config(tmp_path)), run, 0)
    assert job.kept == tmp_path / "results" / "records" / run / "seed-0" / "checkpoint"
    files = {"config.json": '{"type": "smolvla"}', "model.safetensors": "weights", "policy_preprocessor.json": "{}"}
    job.policy_path.mkdir(parents=True)
    for name, text in files.items():
        (job.policy_path / name).write_text(text)
    assert not job.restore_outputs(), "nothing kept yet"
    job.keep_policy()
    shutil.rmtree(job.directory)  # a fresh machine: the ledger and what it keeps, no run folder
    assert job.restore_outputs()
    assert {file.name: file.read_text() for file in job.policy_path.iterdir()} == files
    assert not job.restore_progress(), "a finished run's policy folder is no checkpoint to resume"


@pytest.mark.parametrize(
    ("runs", "message"),
    [
        ('[runs.other]\nlerobot = { smolvlm = "huge" }\n', "[runs.other] lerobot: smolvlm must be one of"),
        ('[runs.other]\nlerobot = { policy_type = "pi0" }\n', "policy_type must be one LeRobot trains from scratch"),
        ("[runs.other]\nlerobot = { chunk_size = 0 }\n", "chunk_size must be an integer of at least 1, got 0"),
        ('[runs.other]\nlerobot = {}\npolicy = { type = "mlp" }\n', "give 'policy' or 'lerobot', not both"),
        ('[runs.other]\ntrainer = "lerobot-train"\n', "'trainer' need a 'teacher' to distill from"),
        ('[runs.other]\nteacher = "teacher"\ntrainer = "accelerate"\n', "trainer must be one of"),
        (
            '[runs.built-in]\n[runs.other]\nteacher = "built-in"\ntrainer = "lerobot-train"\n',
            "trainer 'lerobot-train' does not distil 'built-in', a built-in policy; its trainers: ['snapflow']",
        ),
    ],
)
def test_a_bad_lerobot_run_is_refused_with_its_section_named(tmp_path, capsys, runs, message):
    path = write_config(tmp_path, runs)
    assert main(["sweep", str(path), "--report-only", "--no-progress"]) == 2
    error = capsys.readouterr().err
    assert message in error and "Traceback" not in error


# ~175 s on CI's two cores: the LeRobot sweep end to end, each part at its smallest: a collection, its
# LeRobotDataset, a SmolVLA teacher, a student by each trainer (lerobot-train as a subprocess) and every row evaluated
# (20 steps an episode: what this checks is that every row runs and is recorded, not whether it succeeds).
@pytest.mark.slow
@pytest.mark.lerobot
@pytest.mark.skipif(
    not lerobot_loads_plugins(),
    reason=f"lerobot-train imports snapflow's student types from lerobot {PLUGIN_LEROBOT} on",
)
def test_a_tiny_smolvla_sweep_trains_distils_by_both_trainers_and_evaluates_every_row(tmp_path):
    from snapflow.adapters.lerobot.local_vlm import BUNDLED_VLM

    biased = (
        '[runs.biased]\nteacher = "teacher"\ntrainer = "lerobot-train"\ndistill = { alpha = 1.0, time_shift = 4.0 }\n'
    )
    biased += "train = { steps = 2, batch_size = 4, warmup_steps = 1, log_every = 1, checkpoint_every = 2 }\n"
    biased_row = '\n  { label = "high-noise biased 1-NFE", run = "biased", mode = "naive" },'
    config_path = write_config(tmp_path, biased, biased_row)
    assert main(["sweep", str(config_path), "--workers", "1", "--threads", "1", "--no-progress"]) == 0
    runs = tmp_path / "runs"
    # the high-noise-biased run: flow matching alone at shifted times, so not labelled distilled
    fine_tuned = json.loads(
        (runs / "biased/seed-0/lerobot-train/checkpoints/last/pretrained_model/config.json").read_text()
    )
    biased_settings = fine_tuned["distill"]
    assert (fine_tuned["distilled"], biased_settings["alpha"], biased_settings["time_shift"]) == (False, 1.0, 4.0)
    assert (runs / "lerobot" / "meta" / "info.json").is_file()
    student = json.loads(
        (runs / "lerobot-train/seed-0/lerobot-train/checkpoints/last/pretrained_model/config.json").read_text()
    )
    assert student["type"] == "snapflow_smolvla" and student["distilled"] is True
    assert student["distill"]["consistency_weight"] == 3.0, "snapflow's recipe, as the sweep's default"
    trained_on = json.loads(
        (runs / "lerobot-train/seed-0/lerobot-train/checkpoints/last/pretrained_model/train_config.json").read_text()
    )
    assert trained_on["dataset"]["episodes"] == [0, 1, 3, 4], "the teacher's held-out episode of each task stays out"
    assert "consistency_loss" in (runs / "lerobot-train/seed-0/lerobot-train.log").read_text()
    kept = tmp_path / "results/records/lerobot-train/seed-0/checkpoint/pretrained_model"
    kept_config = json.loads((kept / "config.json").read_text())
    assert kept_config.pop("vlm_model_name") == BUNDLED_VLM, "the SmolVLM travels inside the kept folder"
    assert (kept / BUNDLED_VLM / "tokenizer.json").is_file() and (kept / "model.safetensors").is_file()
    assert kept_config == {key: value for key, value in student.items() if key != "vlm_model_name"}
    resumed_on_another_machine(tmp_path, load_sweep(config_path))
    # the teacher is kept as the policy folder it exported, which opens where the run folder is gone
    teacher = tmp_path / "results/records/teacher/seed-0/checkpoint"
    assert json.loads((teacher / "kept.json").read_text())["checkpoint"] == "lerobot_policy"
    with pytest.raises(CheckpointError, match=f"pass its policy folder {runs / 'teacher/seed-0/lerobot_policy'}"):
        open_policy(runs / "teacher" / "seed-0")
    moved = shutil.copytree(teacher / "lerobot_policy", tmp_path / "elsewhere" / "teacher")
    shutil.rmtree(runs)
    assert not open_policy(moved).distilled
    headline = json.loads((tmp_path / "results" / "results.json").read_text())["tables"]["headline"]["rows"]
    assert [row["episodes"] for row in headline] == [2, 2, 2, 2, 2]
    for row in headline:
        assert 0 <= row["success_mean"] <= 100 and row["offline"]["mse"] >= 0


def resumed_on_another_machine(tmp_path: Path, config) -> None:
    """A lerobot-train run cut after its step-2 checkpoint on a machine that is then gone: its run folder lost, its
    progress kept as the keeper keeps it (each checkpoint as it is saved), the student folder's path as a placeholder.
    Run again, it goes on from step 2 (LeRobot's log starts at step 3), counts its training time on from step 2's
    (the attempt before took 100 s, say), and keeps its finished policy in the end."""
    from snapflow.reporting.files import write_json
    from snapflow.training.lerobot_progress import ELAPSED, STUDENT_FOLDER, keep_lerobot_checkpoint
    from snapflow.training.lerobot_student import lerobot_train_run

    run_folder, job = tmp_path / "runs/lerobot-train/seed-0", train_job(config, "lerobot-train", 0)
    kept_in, step_2 = job.kept, run_folder / "lerobot-train/checkpoints/000002"
    episodes = json.loads((step_2 / "pretrained_model/train_config.json").read_text())["dataset"]["episodes"]
    run = lerobot_train_run(run_folder / "student", job.train, episodes)
    write_json(step_2 / "training_state" / ELAPSED, {"seconds": 100.0})
    kept = keep_lerobot_checkpoint(step_2, kept_in, run_folder / "student", run)
    assert json.loads((kept_in / "kept.json").read_text()) == {"checkpoint": "step_000002", "run": run}
    kept_config = (kept / "pretrained_model/config.json").read_text()
    assert STUDENT_FOLDER in kept_config and str(tmp_path) not in kept_config, "no path of this machine is kept"
    shutil.rmtree(run_folder)
    began = time.perf_counter()
    state = job.run()
    assert 100.0 < state["wall_time_s"] <= 100.0 + time.perf_counter() - began, "the attempts' time, not the last's"
    log = (run_folder / "lerobot-train.log").read_text()
    assert "step:3 " in log and "step:1 " not in log, "resumed at step 2, not from the start"
    last = run_folder / "lerobot-train/checkpoints/last"
    assert json.loads((last / "training_state/training_step.json").read_text())["step"] == 4
    assert str(run_folder / "student") in (last / "pretrained_model/config.json").read_text()
    assert json.loads((kept_in / "kept.json").read_text())["checkpoint"] == "pretrained_model"
    assert not kept.exists(), "the finished policy replaces the progress kept"


LEROBOT_EVAL_TABLE = """
[[tables]]
name = "lerobot-eval"
evaluator = "lerobot-eval"
episodes_per_task = 10
rows = [
  { label = "teacher 10-NFE", run = "teacher", mode = "teacher-10" },
  { label = "SnapFlow 1-NFE, lerobot-train", run = "lerobot-train", mode = "snapflow-1" },
]
"""


def write_libero_config(directory: Path, table: str = LEROBOT_EVAL_TABLE) -> Path:
    """The tiny sweep on LIBERO's first task, with ``table`` after its headline."""
    path = write_config(directory)
    text = path.read_text().replace(
        'tasks = ["reach-v3", "button-press-topdown-v3"]', 'env = "libero"\ntasks = ["libero_spatial_0"]'
    )
    path.write_text(text + table)
    return path


def test_a_table_by_lerobot_eval_evaluates_the_same_policies_into_records_of_its_own(tmp_path):
    config = load_sweep(write_libero_config(tmp_path))
    planned = [job for job in jobs(config) if isinstance(job, EvalJob)]
    by_snapflow = {(job.policy.run_name, job.mode.name): job for job in planned if job.evaluator == "snapflow"}
    by_lerobot = {(job.policy.run_name, job.mode.name): job for job in planned if job.evaluator == "lerobot-eval"}
    assert set(by_lerobot) == {("teacher", "teacher-10"), ("lerobot-train", "snapflow-1")}
    for cell, job in by_lerobot.items():
        assert job.path.name == f"{job.mode.name}_nact4_eps10_lerobot-eval.json"
        settings = job.settings()
        assert settings["evaluator"] == "lerobot-eval" and "offline_samples" not in settings
        # the headline's cell by snapflow's evaluator: the same policy, another record, its settings as they were
        same = by_snapflow[cell]
        assert same.policy == job.policy and same.path != job.path and "evaluator" not in same.settings()
    assert "by lerobot-eval" in by_lerobot[("teacher", "teacher-10")].describe()


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (('evaluator = "lerobot-eval"', 'evaluator = "gym"'), "evaluator must be one of ['snapflow', 'lerobot-eval']"),
        (("episodes_per_task = 10\nrows", "episodes_per_task = 11\nrows"), "at most 10 episodes a task"),
        (("episodes_per_task = 10\nrows", "first_variation = 10\nepisodes_per_task = 10\nrows"), "first_variation 0"),
        (('run = "lerobot-train", mode = "snapflow-1"', 'run = "teacher", mode = "snapflow-1"'), "no jump to sample"),
    ],
)
def test_a_bad_lerobot_eval_table_is_refused_with_its_section_named(tmp_path, capsys, change, message):
    path = write_libero_config(tmp_path, LEROBOT_EVAL_TABLE.replace(*change))
    assert main(["sweep", str(path), "--report-only", "--no-progress"]) == 2
    error = capsys.readouterr().err
    assert "[[tables]] #2" in error and message in error and "Traceback" not in error


def test_lerobot_eval_runs_on_libero_and_on_lerobot_runs_alone(tmp_path, capsys):
    metaworld = write_config(tmp_path)
    metaworld.write_text(metaworld.read_text() + LEROBOT_EVAL_TABLE)
    assert main(["sweep", str(metaworld), "--report-only", "--no-progress"]) == 2
    assert "lerobot-eval evaluates on LeRobot's LIBERO environment; data is 'metaworld'" in capsys.readouterr().err
    built_in = write_libero_config(
        tmp_path,
        '[runs.mlp]\npolicy = { type = "mlp" }\n'
        + LEROBOT_EVAL_TABLE.replace('run = "teacher", mode = "teacher-10"', 'run = "mlp", mode = "teacher-10"'),
    )
    assert main(["sweep", str(built_in), "--report-only", "--no-progress"]) == 2
    assert "lerobot-eval evaluates this sweep's LeRobot runs and their students" in capsys.readouterr().err


def test_a_lerobot_eval_rows_finished_tasks_are_kept_and_go_on_from_the_next_on_a_fresh_machine(tmp_path):
    """By lerobot-eval a row runs task by task, 16 min a LIBERO task: each finished task's files are kept beside the
    row's ledger record with the job they belong to, and a fresh machine reads them back instead of running them
    again; tasks kept without their job are not read; the row does not need the demonstrations back."""
    from snapflow.evaluation.lerobot_eval import EVAL_INFO, TIMING, run_lerobot_eval
    from snapflow.flow.modes import SNAPFLOW_1
    from snapflow.jobs.runner import record
    from snapflow.jobs.sweep.eval_jobs import KEPT_JOB
    from snapflow.reporting.files import write_json

    config = load_sweep(write_libero_config(tmp_path))
    (job,) = [
        job
        for job in jobs(config)
        if isinstance(job, EvalJob) and job.evaluator == "lerobot-eval" and job.mode.name == "snapflow-1"
    ]
    assert job.reads_outputs_of(job.policy) and not job.reads_outputs_of(job.policy.data)
    kept = job.kept_progress
    assert kept == job.ledger_path.with_suffix("")
    task = "libero_spatial_0"
    eval_info = {"per_task": [{"task_group": "libero_spatial", "task_id": 0, "metrics": {"successes": [True, False]}}]}
    write_json(kept / task / EVAL_INFO, eval_info)
    write_json(kept / task / TIMING, {"wall_time_s": 960.0})
    assert not job.restore_progress(), "tasks kept without the job they belong to are not this job's"
    write_json(kept / KEPT_JOB, record(job))
    assert job.restore_progress()
    # read back as a finished task: no lerobot-eval runs (there is no policy folder to run), its files kept again
    row = run_lerobot_eval(tmp_path / "no-policy", [task], 2, 32, 2, SNAPFLOW_1, job.episodes_dir, kept=kept)
    assert (row.success[task].successes, row.success[task].episodes, row.closed_loop_s) == (1, 2, 960.0)
    assert json.loads((kept / task / TIMING).read_text()) == {"wall_time_s": 960.0}
