"""A sweep's config: refused with its section named when it is wrong, rows that read another sweep's records, and the
committed results rendering to the committed Markdown."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import pytest

from snapflow.cli import main
from snapflow.flow.realtime_settings import RealTimeChunking
from snapflow.jobs.sweep import EvalJob, TrainJob, jobs, load_sweep, plan, replace_block
from snapflow.jobs.sweep.aggregate import TableResult
from snapflow.jobs.sweep.markdown import markdown_blocks, tables_markdown
from snapflow.jobs.sweep.planning import eval_job, train_job
from snapflow.jobs.sweep.results import write_results
from tests.jobs.tiny_sweep import ROOT, TINY_TRAIN, write_config


@pytest.mark.parametrize(
    ("name", "page"),
    [
        *(
            (name, "metaworld")
            for name in ("mt10-state", "mt10-camera", "mt10-via-points", "mt10-levers", "mt50-state")
        ),
        *((name, "libero") for name in ("libero-spatial", "libero-object", "smolvla-libero-four-suites")),
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
            '[runs.teacher]\nlerobot = { policy_type = "smolvla" }\n[runs.biased]\nteacher = "teacher"\n'
            'trainer = "lerobot-train"\n'
            'distill = { alpha = 1.0, time_shift = 4.0 }\n[[tables]]\nname = "t"\nrows = [{ label = "x", run = "biased", mode = "snapflow-1" }]\n',
            "run 'biased' trains no jump (alpha 1 or lambda 0): sample it as naive or teacher-N",
        ),
        (
            '[runs.teacher]\n[runs.student]\nteacher = "teacher"\ndistill = { time_shift = -1 }\n',
            "a time shift must be positive, got -1",
        ),
        (
            '[runs.teacher]\ntrain = { time_distribution = "beta:0" }\n',
            "[runs.teacher] train: TrainConfig.time_distribution: beta:A takes a positive, finite A, got 'beta:0'",
        ),
        (
            '[runs.teacher]\n[runs.student]\nteacher = "teacher"\ntrain = { time_distribution = "beta:1.5" }\n',
            "[runs.student] train: time_distribution 'beta:1.5' is a teacher's setting: a student's flow-matching rows "
            "draw its teacher's times",
        ),
        (
            '[runs.teacher]\nlerobot = { policy_type = "smolvla" }\ntrain = { time_distribution = "shift:4" }\n',
            "[runs.teacher] train: a LeRobot teacher trains on its own type's flow-matching times",
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
        (
            '[runs.teacher]\n[[tables]]\nname = "t"\nrows = [{ label = "x", run = "teacher", mode = "naive", rtc = { kind = "guided" } }]\n',
            "row 'x': rtc: missing key(s) ['delay']",
        ),
        (
            '[runs.teacher]\n[[tables]]\nname = "t"\nrows = [{ label = "x", run = "teacher", mode = "naive", rtc = { delay = -1 } }]\n',
            "row 'x': rtc: an inference delay is a whole number of actions, 0 or more, got -1",
        ),
        (
            '[runs.teacher]\n[runs.s]\nteacher = "teacher"\n[[tables]]\nname = "t"\n'
            'rows = [{ label = "x", run = "s", mode = "snapflow-1", rtc = { delay = 2, kind = "guided" } }]\n',
            "row 'x': rtc: guided real-time chunking steers Euler steps; snapflow-1 jumps",
        ),
        (
            '[runs.teacher]\n[[tables]]\nname = "t"\nrows = [{ label = "x", run = "teacher", mode = "naive", rtc = { delay = 1, lag = 2 } }]\n',
            "row 'x': rtc: unknown key(s) ['lag']",
        ),
        (
            '[runs.teacher]\n[[tables]]\nname = "t"\nrows = [{ label = "x", run = "teacher", mode = "naive", rtc = { delay = 5 } }]\n',
            "row 'x': rtc: a delay of 5 needs delay <= n_act, got n_act 4",
        ),
        (
            '[runs.teacher]\n[runs.s]\nteacher = "teacher"\n[[tables]]\nname = "t"\n'
            'rows = [{ label = "x", run = "s", mode = "snapflow-1", rtc = { delay = 2, kind = "trained" } }]\n',
            "row 'x': rtc: 'trained' at a delay of 2 needs run 's' distilled with rtc_max_delay at least 2, got 0",
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


def test_a_teacher_runs_train_table_names_its_time_distribution_and_its_job_records_it(tmp_path):
    """The teacher's flow-matching times are part of its job's settings (another key, so another run) only where they
    are not the old uniform: a sweep that names none keeps the records and keys it had; its students follow it."""
    for name in ("uniform", "biased"):
        (tmp_path / name).mkdir()
    uniform = load_sweep(write_config(tmp_path / "uniform"))
    biased = load_sweep(
        write_config(tmp_path / "biased", teacher_train=TINY_TRAIN[:-1] + ', time_distribution = "shift:4.0" }')
    )
    assert uniform.runs["teacher"].train.time_distribution == "uniform"
    assert biased.runs["teacher"].train.time_distribution == "shift:4"
    assert "time_distribution" not in train_job(uniform, "teacher", 0).settings()["train"]
    assert train_job(biased, "teacher", 0).settings()["train"]["time_distribution"] == "shift:4"
    for run in ("teacher", "snapflow"):  # a student's key holds its teacher's
        assert train_job(uniform, run, 0).key != train_job(biased, run, 0).key
    assert train_job(uniform, "snapflow", 0).settings() == train_job(biased, "snapflow", 0).settings()


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


def test_a_row_under_real_time_chunking_is_an_evaluation_of_its_own_that_records_its_setting(tmp_path):
    """The delay sweep's rows: each (mode, delay, kind) its own record, named by its delay and kind; a row without
    rtc keeps the name and settings evaluations had before rows could set it."""
    config = load_sweep(ROOT / "configs" / "sweeps" / "mt10-state.toml")
    (table,) = config.only(["delay"]).tables
    jobs = [eval_job(config, table, row, 0) for row in table.rows]
    assert len({job.path for job in jobs}) == 9
    trained = jobs[-1]
    assert trained.path.name == "snapflow-1_nact4_eps50_rtc-d4-trained.json", "default settings: delay and kind"
    steered = replace(table.rows[1], rtc=RealTimeChunking(2, "guided", max_guidance_weight=5))
    same = replace(table.rows[1], rtc=RealTimeChunking(2, "guided", max_guidance_weight=5.0))
    named = eval_job(config, table, steered, 0).path.name
    assert (
        named.startswith("teacher-10_nact4_eps50_rtc-d2-guided-")
        and named == eval_job(config, table, same, 0).path.name
    )
    assert trained.settings()["rtc"] == {**RealTimeChunking(4, "trained").to_dict()}
    assert "delay 4, rtc trained" in trained.describe()
    assert config.runs["snapflow-rtc"].distill.rtc_max_delay == 4
    plain = eval_job(config, table, replace(table.rows[0], rtc=None), 0)
    assert plain.path.name == "teacher-10_nact4_eps50.json" and "rtc" not in plain.settings()


def test_replace_block_appends_a_missing_block_and_replaces_an_existing_one():
    document = "# R\n\ntext\n"
    once = replace_block(document, "a/b", "first")
    assert once == "# R\n\ntext\n\n<!-- sweep:a/b -->\nfirst\n<!-- /sweep:a/b -->\n"
    assert replace_block(once, "a/b", "second") == once.replace("first", "second")
    assert replace_block(once, "a/b", "x\\1").count("x\\1") == 1  # bodies are literal text, not regex templates


@pytest.mark.parametrize("default", ["paper", "modes-lean"])
def test_every_committed_sweep_keeps_its_job_keys_whatever_the_default_recipe_becomes(monkeypatch, default):
    """A sweep whose students took the default recipe would change every student's key (and lose its committed
    records) the day the default changes: each names its recipe, so another default leaves every key as it is."""
    import snapflow.jobs.sweep.schema as schema

    monkeypatch.chdir(ROOT)
    paths = sorted(Path("configs/sweeps").glob("*.toml"))
    keys = {path.name: sorted(job.key for job in jobs(load_sweep(path))) for path in paths}
    monkeypatch.setattr(schema, "DEFAULT_RECIPE", default)
    assert {path.name: sorted(job.key for job in jobs(load_sweep(path))) for path in paths} == keys
