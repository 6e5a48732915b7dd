"""``snapflow sweep CONFIG --status``: each job done, kept, running or missing, and the machine time left, estimated
from the measured times of finished jobs of the same kind; run as a user runs it, from another folder."""

from __future__ import annotations

import subprocess
from dataclasses import replace
from pathlib import Path

import pytest

from snapflow.jobs.runner import _start, record, write_record
from snapflow.jobs.sweep import load_sweep, plan
from snapflow.jobs.sweep.planning import data_job, eval_job, train_job
from snapflow.reporting.locks import hold_run_lock
from tests.jobs.tiny_sweep import write_config
from tests.reporting.test_archive import SNAPFLOW


def status(config_path: Path, cwd: Path, *arguments: str) -> list[str]:
    result = subprocess.run(
        [*SNAPFLOW, "sweep", str(config_path), "--status", *arguments], cwd=cwd, capture_output=True, text=True
    )
    assert result.returncode == 0, result.stderr
    return result.stdout.splitlines()


def line_of(lines: list[str], words: str) -> str:
    (found,) = [line for line in lines if words in line]
    return found


@pytest.mark.slow  # ~20 s: the command run four times as a user runs it
def test_the_status_names_each_jobs_state_and_estimates_the_time_left_from_measured_jobs(tmp_path):
    config_path = write_config(tmp_path, seeds="[0]")
    config = load_sweep(config_path)
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    lines = status(config_path, elsewhere)
    assert lines[0] == f"tiny: {len(lines) - 2} jobs: 0 done, 0 kept, 0 running, {len(lines) - 2} missing"
    assert lines[-1].startswith("machine time left: ~0.0 h for 0 jobs")

    # both collections finished here (times measured), the teacher recorded only in the committed ledger
    reach, push = data_job(config).parts
    write_record(reach, {"wall_time_s": 600.0})
    write_record(push, {"wall_time_s": 1200.0})
    teacher = train_job(config, "teacher", 0)
    write_record(teacher, {"wall_time_s": 3600.0})
    teacher.record_path.unlink()  # as on a fresh clone of the sweep: its result known, its folder not here
    # a student started and interrupted, another seed's evaluation running under the sweep's lock
    student = train_job(config, "snapflow", 0)
    _start(student)
    lines = status(config_path, elsewhere)
    assert line_of(lines, "collect reach-v3").split()[:1] == ["done"] and "10.0 min" in line_of(lines, "reach-v3")
    assert line_of(lines, "train teacher seed 0").startswith("  kept") and "60.0 min" in line_of(
        lines, "train teacher seed 0"
    )
    assert line_of(lines, "train snapflow seed 0").startswith("  missing") and "started" in line_of(
        lines, "train snapflow seed 0"
    )
    # a student's time is estimated from the only training measured (the teacher's hour)
    assert "~60.0 min" in line_of(lines, "train snapflow seed 0")
    assert "~60.0 min" in line_of(lines, "train meanflow seed 0")

    evaluation = eval_job(config, config.tables[0], config.tables[0].rows[0], 0)
    with hold_run_lock(config.output_dir, "snapflow sweep"):  # a sweep now runs, and has started the evaluation
        _start(evaluation)
        lines = status(config_path, elsewhere, "--workers", "2")
    assert line_of(lines, evaluation.describe().removeprefix("tiny: ")).startswith("  running")
    assert line_of(lines, "train snapflow seed 0").startswith("  missing") and "started" in line_of(
        lines, "train snapflow seed 0"
    ), "interrupted before this sweep began: not running, though the sweep could go on with it"
    counts = lines[0].split(": ")[-1]
    missing = len(plan(config)) - 2  # the running job is not missing
    assert counts.startswith("2 done, 1 kept, 1 running") and f"{missing} missing" in counts
    assert "on 2 workers" in lines[-1] and "of kinds never measured here" in lines[-1], "no evaluation measured"


def test_jobs_never_measured_are_counted_one_by_one_and_each_reads_as_its_own(tmp_path):
    """The time-distribution sweep evaluates each policy twice, on variations 20-39 and 0-19 (its two tables): the
    summary counts all 83 jobs (10 collections, the data, 18 runs, 54 evaluations), and each reads as its own."""
    from snapflow.jobs.sweep.status import format_status, sweep_status

    config = load_sweep(
        Path(__file__).resolve().parents[2] / "configs" / "sweeps" / "mt10-camera-time-distribution.toml"
    )
    config = replace(config, output_dir=tmp_path / "runs", results_dir=tmp_path / "results")  # nothing run yet
    lines = format_status(config, sweep_status(config)).splitlines()
    assert lines[0] == "mt10-camera-time-distribution: 83 jobs: 0 done, 0 kept, 0 running, 83 missing"
    assert lines[-1] == "machine time left: ~0.0 h for 0 jobs, and 83 of kinds never measured here"
    assert len(set(lines[1:-1])) == 83, "two jobs read alike"
    assert any("(teacher-10; n_act 4; from variation 20)" in line for line in lines)


def test_an_evaluation_of_a_kind_never_measured_is_estimated_per_episode_from_the_others(tmp_path):
    """A row of one suite's 100 episodes is not a row of four suites' 400: an evaluation of another kind estimates it
    by its time per episode (a run's training, by the run's time)."""
    from snapflow.jobs.sweep.status import sweep_status

    config = load_sweep(write_config(tmp_path, seeds="[0]"))
    (headline,) = [table for table in config.tables if table.name == "headline"]
    measured = eval_job(config, headline, headline.rows[0], 0)  # 2 tasks x 2 episodes
    write_record(measured, {"closed_loop_s": 400.0})
    statuses = {status.job: status.seconds for status in sweep_status(config)}
    assert statuses[measured] == 400.0
    longer = replace(headline, name="longer", episodes_per_task=3)
    config = replace(config, tables=(*config.tables, longer))
    statuses = {status.job: status.seconds for status in sweep_status(config)}
    assert statuses[eval_job(config, longer, longer.rows[1], 0)] == pytest.approx(400.0 / 4 * 6)


def test_an_unfinished_job_shows_how_far_it_came_here_or_elsewhere_and_only_what_is_left_is_estimated(tmp_path):
    """A row of 400 episodes interrupted at 230 has 170 left, and a run kept at step 1,500 of 4,000 has 2,500: each
    says so, and the time left counts only that part. The progress is read here (the episode log of an evaluation
    started here) or from what another machine kept beside the committed records (a fresh clone), and never from
    another job's."""
    import torch

    from snapflow.evaluation.episode_log import EpisodeLog, FinishedWave
    from snapflow.evaluation.results import EpisodeResult
    from snapflow.jobs.sweep.status import format_status, sweep_status
    from snapflow.training.checkpoint import keep_checkpoint

    config = load_sweep(write_config(tmp_path, seeds="[0]", commit_checkpoint=True))
    (headline,) = [table for table in config.tables if table.name == "headline"]
    measured, evaluation = (eval_job(config, headline, row, 0) for row in headline.rows[:2])
    write_record(measured, {"closed_loop_s": 400.0})  # 2 tasks x 2 episodes: 100 s an episode
    _start(evaluation)
    episodes = [EpisodeResult("reach-v3", variation, True, 10) for variation in range(3)]
    log = EpisodeLog(evaluation.episodes_dir / "row.jsonl", {"row": "snapflow"}, resume=False)
    log.append(FinishedWave(episodes, 1.0, torch.zeros(4, dtype=torch.uint8)))
    with (evaluation.episodes_dir / "row.jsonl").open("a") as file:
        file.write('{"episodes": [')  # a wave cut short by a kill counts for nothing
    teacher = train_job(config, "teacher", 0)
    step = tmp_path / "step_000003"
    step.mkdir()
    (step / "model.safetensors").write_bytes(b"weights")
    keep_checkpoint(step, teacher.kept, {"job": {"another": "job's settings"}, "finished": False})
    by_job = {status.job: status for status in sweep_status(config)}
    assert (by_job[evaluation].progress.done, by_job[evaluation].progress.total) == (3, 4)
    assert by_job[evaluation].seconds == pytest.approx(400.0 / 4), "one episode of four left, at 100 s each"
    assert by_job[teacher].progress is None, "another job's kept checkpoint is not this one's progress"

    keep_checkpoint(step, teacher.kept, {"job": record(teacher), "finished": False})  # kept by another machine
    lines = format_status(config, sweep_status(config)).splitlines()
    assert "(3 of 4 episodes done; goes on from there)" in line_of(lines, evaluation.describe().removeprefix("tiny: "))
    assert "(3 of 12 steps done; goes on from there)" in line_of(lines, "train teacher seed 0")


def test_an_evaluation_never_measured_is_estimated_first_from_others_as_costly_a_chunk(tmp_path):
    """Another policy's row with as many passes a chunk and actions a chunk on the same episodes estimates a row better
    than the time per episode of every row (LIBERO-10 at one action a chunk took 38-46 min, at eight 14)."""
    from snapflow.jobs.sweep.status import sweep_status

    config = load_sweep(write_config(tmp_path, seeds="[0]"))
    (headline,) = [table for table in config.tables if table.name == "headline"]
    ten_steps, one_step = (eval_job(config, headline, row, 0) for row in headline.rows[:2])
    write_record(ten_steps, {"closed_loop_s": 400.0})
    write_record(one_step, {"closed_loop_s": 100.0})
    another = replace(headline.rows[0], label="a student at 10 NFE", run="meanflow")
    config = replace(config, tables=(*config.tables, replace(headline, name="another", rows=(another,))))
    (table,) = [table for table in config.tables if table.name == "another"]
    statuses = {status.job: status.seconds for status in sweep_status(config)}
    assert statuses[eval_job(config, table, another, 0)] == 400.0, "not the mean per episode of both rows (250)"
