"""`snapflow sweep`: a tiny sweep run for real (Meta-World, training, evaluation, files on disk)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from snapflow.cli import main
from snapflow.experiments.sweep import load_sweep, plan, replace_block

TINY_POLICY = "{ prefix_width = 32, expert_width = 32, num_layers = 1, num_heads = 2, head_dim = 16 }"
TINY_TRAIN = "{ steps = 12, batch_size = 16, warmup_steps = 2, log_every = 4, validate_every = 6, checkpoint_every = 6 }"


def write_config(directory: Path, seeds: str = "[0, 1]", extra_rows: str = "") -> Path:
    path = directory / "tiny.toml"
    path.write_text(f"""
name = "tiny"
title = "two tasks, tiny policies"
seeds = {seeds}
output_dir = "{(directory / 'runs').as_posix()}"
results_dir = "{(directory / 'results').as_posix()}"

[data]
tasks = ["reach-v3", "push-v3"]
episodes_per_task = 3

[runs.teacher]
policy = {TINY_POLICY}
train = {TINY_TRAIN}
[runs.snapflow]
teacher = "teacher"
distill = {{ target_steps = [2, 4] }}
train = {TINY_TRAIN}
[runs.meanflow]
teacher = "teacher"
distill = {{ method = "meanflow" }}
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


def test_a_sweep_runs_caches_and_writes_its_tables_into_the_document(tmp_path, capsys):
    config_path = write_config(tmp_path)
    document = tmp_path / "RESULTS.md"
    document.write_text("# Results\n\nProse before.\n\n<!-- sweep:tiny/headline -->\nold table\n<!-- /sweep:tiny/headline -->\n\nProse after.\n")
    jobs = plan(load_sweep(config_path))
    # collect; teacher x2 seeds; snapflow x2, meanflow x1; evaluations: one group per (run, seed, n_act)
    assert sum(job[0] == "collect" for job, _ in jobs) == 1
    assert sorted(job[1:] for job, _ in jobs if job[0] == "train") == [("meanflow", 0), ("snapflow", 0), ("snapflow", 1), ("teacher", 0), ("teacher", 1)]
    assert sum(job[0] == "eval" for job, _ in jobs) == 5

    assert main(["sweep", str(config_path), "--workers", "2", "--document", str(document), "--no-progress"]) == 0
    results = json.loads((tmp_path / "results" / "results.json").read_text())
    headline = results["tables"]["headline"]["rows"]
    assert [row["label"] for row in headline] == ["teacher 10-NFE", "SnapFlow 1-NFE"]
    for row in headline:
        assert row["episodes"] == 2 * 2 * 2  # tasks x episodes per task x seeds
        assert len(row["success_per_seed"]) == 2 and row["success_mean"] == pytest.approx(sum(row["success_per_seed"]) / 2)
        assert 0 <= row["offline"]["mse"] and -1 <= row["offline"]["cosine"] <= 1
        assert all(seconds > 0 for seconds in row["training_s"])
    for seed in (0, 1):  # the table's numbers are the cached evaluation files'
        cached = json.loads((tmp_path / "runs" / "evals" / "teacher" / f"seed-{seed}" / "teacher-10_nact4_eps2.json").read_text())
        assert headline[0]["success_per_seed"][seed] == pytest.approx(100 * cached["success"]["mean"]["success_rate"])
    for name in ("headline.png", "nfe.png", "tables.md"):
        assert (tmp_path / "results" / name).stat().st_size > 0

    text = document.read_text()
    assert "Prose before." in text and "Prose after." in text and "old table" not in text
    assert "| SnapFlow 1-NFE | 1 | 4 |" in text and "<!-- sweep:tiny/nfe -->" in text
    assert "](results/headline.png)" in text and "seeds 0, 1" in text

    assert plan(load_sweep(config_path)) == []  # everything is cached: a second run does nothing
    write_config(tmp_path, seeds="[0, 1, 2]")
    new = plan(load_sweep(config_path))  # a new seed runs only what it needs
    assert sorted(job[1:] for job, _ in new if job[0] == "train") == [("snapflow", 2), ("teacher", 2)]
    assert {job[1].seed for job, _ in new if job[0] == "eval"} == {2}


@pytest.mark.parametrize("mistake, message", [
    ('[data]\nepisodes = 3\n', "unknown key(s) ['episodes']"),
    ('[runs.teacher]\npolicy = { width = 3 }\n', "unknown key(s) ['width']"),
    ('[runs.student]\nteacher = "nobody"\n', "teacher 'nobody' is not a teacher run"),
    ('[runs.teacher]\nseeds = [0]\n[runs.student]\nteacher = "teacher"\nseeds = [1]\n', "seeds [1] have no 'teacher' teacher"),
    ('[runs.teacher]\ntrain = { steps = 0 }\n', "TrainConfig.steps must be at least 1"),
    ('[runs.teacher]\n[runs.student]\nteacher = "teacher"\ndistill = { method = "dance" }\n', "unknown distillation method 'dance'"),
    ('[runs.teacher]\n[runs.student]\nteacher = "teacher"\ndistill = { target = "bootstrap", target_steps = 6 }\n', "power of two"),
    ('[runs.teacher]\n[[tables]]\nname = "t"\nrows = [{ label = "x", run = "ghost", mode = "naive" }]\n', "unknown run 'ghost'"),
    ('[runs.teacher]\n[[tables]]\nname = "t"\nrows = [{ label = "x", run = "teacher", mode = "fast" }]\n', "unknown sampling mode 'fast'"),
    ('[runs.teacher]\n[[tables]]\nname = "t"\nseeds = [5]\nrows = [{ label = "x", run = "teacher", mode = "naive" }]\n', "needs seeds [5]"),
    ('[data]\ntasks = ["fly-v3"]\n', "unknown Meta-World task(s) ['fly-v3']"),
    ('seeds = "all"\n', "seeds must be a non-empty list of integers"),
    ('[runs.teacher\n', "not valid TOML"),
    ('runs = 3\n', "[runs]: expected a table"),
    ('[runs.teacher]\n[[tables]]\nname = "t"\nrows = 3\n', "rows must be a list"),
    ('[runs.teacher]\n[[tables]]\nname = "t"\nrows = [3]\n', "row: expected a table"),
])
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


def test_replace_block_appends_a_missing_block_and_replaces_an_existing_one():
    document = "# R\n\ntext\n"
    once = replace_block(document, "a/b", "first")
    assert once == "# R\n\ntext\n\n<!-- sweep:a/b -->\nfirst\n<!-- /sweep:a/b -->\n"
    assert replace_block(once, "a/b", "second") == once.replace("first", "second")
    assert replace_block(once, "a/b", "x\\1") .count("x\\1") == 1  # bodies are literal text, not regex templates


def test_report_only_on_an_unfinished_sweep_names_what_is_missing(tmp_path, capsys):
    assert main(["sweep", str(write_config(tmp_path)), "--report-only", "--no-progress"]) == 2
    assert "table 'headline' is incomplete" in capsys.readouterr().err
