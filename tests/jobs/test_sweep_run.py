"""A tiny sweep run for real (slow: Meta-World, training, evaluation, files on disk), its cache and its tables in
the document; an output folder another process holds refused."""

from __future__ import annotations

import json
import shutil

import pytest

from snapflow.cli import main
from snapflow.jobs.runner import read_record
from snapflow.jobs.sweep import load_sweep, plan, run_sweeps
from snapflow.jobs.sweep.planning import train_job
from snapflow.jobs.sweep.results import write_results
from tests.jobs.tiny_sweep import write_config

# the teacher under an inference delay of 2 actions, its chunks continuing each other by guided real-time chunking
DELAYED_ROW = (
    '\n  { label = "teacher 10-NFE, d 2", run = "teacher", mode = "teacher-10", rtc = { delay = 2, kind = "guided" } },'
)
CUT = 20  # steps an episode: the tiny policies succeeded in none of 28 episodes run to Meta-World's 500 either


# ~150 s on CI's two cores: the sweep's one end-to-end run on a simulator (collection, teachers, students, every
# table) then its cache and rerun rules on the same folders; each part is at its smallest.
@pytest.mark.slow
def test_a_sweep_runs_caches_reruns_a_changed_student_and_writes_its_tables_into_the_document(tmp_path, capsys):
    config_path = write_config(tmp_path, extra_rows=DELAYED_ROW, max_episode_steps=CUT)
    document = tmp_path / "RESULTS.md"
    document.write_text(
        "# Results\n\nProse before.\n\n<!-- sweep:tiny/headline -->\nold table\n<!-- /sweep:tiny/headline -->\n\nProse after.\n"
    )
    assert main(["sweep", str(config_path), "--workers", "2", "--document", str(document), "--no-progress"]) == 0
    results = json.loads((tmp_path / "results" / "results.json").read_text())
    headline = results["tables"]["headline"]["rows"]
    assert [row["label"] for row in headline] == ["teacher 10-NFE", "SnapFlow 1-NFE", "teacher 10-NFE, d 2"]
    for row in headline:
        assert row["episodes"] == 2 * 2 * 2  # tasks x episodes per task x seeds
        assert len(row["success_per_seed"]) == 2 and row["success_mean"] == pytest.approx(
            sum(row["success_per_seed"]) / 2
        )
        assert 0 <= row["offline"]["mse"] and -1 <= row["offline"]["cosine"] <= 1
        assert all(seconds > 0 for seconds in row["training_s"])
    teacher_row, student_row, delayed_row = headline
    assert "switches" not in teacher_row, "the chunk switches are measured under real-time chunking"
    switches = delayed_row["switches"]  # 20 steps, a chunk every 4: switches at 4, 8, 12, 16 of every episode
    assert switches["switches"] == 4 * 8 and switches["jump_at_switches"] > 0 and switches["jerk_elsewhere"] > 0
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
        for run, name in (
            ("teacher", "teacher-10_nact4_eps2_cut20.json"),
            ("snapflow", "snapflow-1_nact4_eps2_cut20.json"),
        )
    }
    assert student_row["difference"]["mean"] == pytest.approx(sum(cells["snapflow"]) / 4 - sum(cells["teacher"]) / 4)
    for seed in (0, 1):  # the table's numbers are the cached evaluation records'
        cached = json.loads(
            (tmp_path / "runs" / "evals" / "teacher" / f"seed-{seed}" / "teacher-10_nact4_eps2_cut20.json").read_text()
        )
        assert headline[0]["success_per_seed"][seed] == pytest.approx(100 * cached["success"]["mean"]["success_rate"])
        # its episodes, logged as they finished (what an interrupted evaluation goes on from)
        log = (
            tmp_path
            / "runs"
            / "evals"
            / "teacher"
            / f"seed-{seed}"
            / "teacher-10_nact4_eps2_cut20.episodes"
            / "00-teacher-10.jsonl"
        )
        waves = [json.loads(line)["episodes"] for line in log.read_text().splitlines()[1:]]
        assert sum(episode["success"] for wave in waves for episode in wave) == cached["success"]["mean"]["successes"]
        assert max(episode["steps"] for wave in waves for episode in wave) == CUT, "cut at the table's limit"
    for name in ("headline.png", "nfe.png", "tables.md"):
        assert (tmp_path / "results" / name).stat().st_size > 0

    text = document.read_text()
    assert "Prose before." in text and "Prose after." in text and "old table" not in text
    assert "| SnapFlow 1-NFE | 1 | 4 |" in text and "<!-- sweep:tiny/nfe -->" in text
    assert "How smoothly the chunks joined" in text and "| teacher 10-NFE, d 2 | 32 |" in text
    assert "](results/headline.png)" in text and "seeds 0, 1" in text and f"every episode cut at {CUT} steps" in text
    assert plan(load_sweep(config_path)) == []  # everything is cached: a second run does nothing

    runs = tmp_path / "runs"
    for run in ("teacher", "meanflow"):
        (runs / run / "seed-0" / "left-over.txt").write_text("made with the old settings")
    records = {path: path.stat().st_mtime_ns for path in runs.rglob("*.json")}
    write_config(
        tmp_path,
        extra_rows=DELAYED_ROW,
        meanflow_distill='{ method = "meanflow", alpha = 0.7 }',
        max_episode_steps=CUT,
    )
    times = run_sweeps([load_sweep(config_path)], workers=2, progress=False)
    assert set(times) == {"tiny: train meanflow seed 0", "tiny: evaluate meanflow seed 0 (snapflow-1; n_act 4)"}
    rewritten = {
        path.relative_to(runs).as_posix()
        for path, stamp in records.items()
        if not path.is_file() or path.stat().st_mtime_ns != stamp
    }
    assert {path for path in rewritten if not path.startswith("meanflow/seed-0/")} == {
        "evals/meanflow/seed-0/snapflow-1_nact4_eps2_cut20.json"
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
