"""commit_checkpoint for real (slow): a kept policy evaluated on a fresh machine, a kept unfinished run continued there."""

from __future__ import annotations

import json
import shutil

import pytest

from snapflow.jobs.runner import run_jobs
from snapflow.jobs.sweep import load_sweep, plan, run_sweeps
from snapflow.jobs.sweep.planning import train_job
from tests.jobs.tiny_sweep import DATA, TINY_TRAIN, names, write_config


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

    config = load_sweep(write_config(tmp_path, seeds="[0]", commit_checkpoint=True, max_episode_steps=20)).only(
        ["headline"]
    )
    run_sweeps([config], progress=False)
    kept = tmp_path / "results" / "records" / "teacher" / "seed-0" / "checkpoint"
    state = json.loads((kept / "kept.json").read_text())
    assert state["finished"] and state["checkpoint"] == "step_0000012"
    assert sorted(path.name for path in (kept / "step_0000012").iterdir()) == ["policy.json", "policy.safetensors"]
    assert [path.name for path in kept.glob("step_*")] == ["step_0000012"], "only the last checkpoint is kept"
    assert not (tmp_path / "results" / "records" / "snapflow" / "seed-0" / "checkpoint").exists(), "the teacher's alone"
    _an_unrecorded_evaluation_reads_its_kept_waves_back(config, monkeypatch)

    shutil.rmtree(tmp_path / "runs")  # a fresh machine: the ledger and the kept checkpoints committed, nothing else
    extra = '\n  { label = "teacher 2-NFE", run = "teacher", mode = "teacher-2" },'
    config = load_sweep(
        write_config(tmp_path, seeds="[0]", extra_rows=extra, commit_checkpoint=True, max_episode_steps=20)
    ).only(["headline"])
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
        load_sweep(
            write_config(tmp_path, seeds="[0]", teacher_train=more_steps, commit_checkpoint=True, max_episode_steps=20)
        ),
        "teacher",
        0,
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
    train_teacher(teacher.data.directory, never_interrupted, teacher.spec, teacher.train, progress=False)
    last = "checkpoints/step_0000013/policy.safetensors"
    assert (teacher.directory / last).read_bytes() == (never_interrupted / last).read_bytes()


def _an_unrecorded_evaluation_reads_its_kept_waves_back(config, monkeypatch) -> None:
    """An evaluation keeps its episode log whole beside its ledger record, with the job it belongs to, as its waves
    finish: a machine without the row's record and logs reads the kept waves back and runs no episode again."""
    from snapflow.evaluation.closed_loop import ClosedLoopEvaluator
    from snapflow.jobs.sweep import EvalJob, jobs
    from snapflow.jobs.sweep.eval_jobs import KEPT_JOB

    (job,) = [job for job in jobs(config) if isinstance(job, EvalJob) and job.mode.name == "teacher-10"]
    kept = job.kept_progress
    assert kept == job.ledger_path.with_suffix("")
    assert sorted(path.name for path in kept.iterdir()) == ["00-teacher-10.jsonl", KEPT_JOB]
    assert (kept / "00-teacher-10.jsonl").read_text() == (job.episodes_dir / "00-teacher-10.jsonl").read_text()
    recorded = json.loads(job.ledger_path.read_text())["success"]
    job.ledger_path.unlink()
    job.record_path.unlink()
    shutil.rmtree(job.episodes_dir)

    def no_episode(*args, **kwargs):
        raise AssertionError("a kept wave was run again")

    with monkeypatch.context() as patched:
        patched.setattr(ClosedLoopEvaluator, "_environments", no_episode)
        assert set(run_jobs([job], progress=False)) == {job.describe()}
    assert json.loads(job.ledger_path.read_text())["success"] == recorded, "the kept waves' episodes, as they were"
