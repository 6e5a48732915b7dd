"""`snapflow sweep --backend ray` against a Ray head started here on the loopback (2 CPUs, a 200 MB object store) and
stopped whatever the outcome: the same tiny sweep run by the local runner and on Ray writes the same files, byte for
byte but for the wall times they measure; a failed job is told as the local runner tells it; a node that does not see
the sweep's folder is refused before any job starts; and the refusals that need no cluster."""

from __future__ import annotations

import json
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

import snapflow
from snapflow.errors import SnapflowError
from snapflow.jobs.runner import is_done, read_record, run_jobs
from tests.jobs.test_runner import KilledJob, LogJob, SlowJob
from tests.jobs.tiny_sweep import ROOT, TINY_POLICY, TINY_TRAIN

SNAPFLOW = [sys.executable, "-m", "snapflow.cli"]
# relative folders: a Ray task runs in the folder the sweep started from, so its records hold the same paths
CONFIG = f"""
name = "tiny"
title = "tiny, local and on Ray"
seeds = [0]
output_dir = "runs"
results_dir = "results"

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

[[tables]]
name = "headline"
title = "tiny headline"
episodes_per_task = 2
max_episode_steps = 20
per_task = true
rows = [
  {{ label = "teacher 10-NFE", run = "teacher", mode = "teacher-10" }},
  {{ label = "SnapFlow 1-NFE", run = "snapflow", mode = "snapflow-1" }},
]
"""
# what a record, log or table holds that is measured, not computed: the wall times of the run that wrote it
MEASURED_KEYS = {"wall_time_s", "closed_loop_s", "evaluation_s", "training_s", "step_s", "seconds"}
MEASURED_COLUMN = " s / training step "
MEASURED_CAPTION = re.compile(r"wall time: evaluation [\d.]+ min for the table, training [\d.]+-[\d.]+ min")
LOCK = ".snapflow.lock"  # holds its holder's pid


@dataclass(frozen=True)
class RayHead:
    """A Ray head on the loopback; ``hidden``: a folder its workers see as an empty one of their own (None where this
    machine gives no private mount namespace)."""

    address: str
    hidden: Path | None


def _free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


def _private_mounts() -> bool:
    """Whether a process can be started in a mount namespace of its own (root, or unprivileged namespaces)."""
    if shutil.which("unshare") is None:
        return False
    return subprocess.run(["unshare", "--mount", "true"], capture_output=True).returncode == 0


def _end_session(session: int) -> None:
    """SIGKILL each process left in the session the head started (every Ray process it spawned), by its id."""
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rpartition(")")[2].split()
        except OSError:
            continue  # ended meanwhile
        if int(fields[3]) == session:  # after the name: state, parent, group, session
            try:
                os.kill(int(stat.parent.name), signal.SIGKILL)
            except ProcessLookupError:
                pass


@pytest.fixture(scope="module")
def ray_head(tmp_path_factory: pytest.TempPathFactory) -> Iterator[RayHead]:
    """``ray start --head --block``, reached on the loopback, its workers importing this checkout's snapflow and tests,
    in a mount namespace where ``hidden`` is an empty tmpfs; stopped (SIGTERM, then whatever is left of its session) on
    leaving, whatever the outcome. (Ray 2.60 names its node by the machine's address even when told 127.0.0.1, and
    its servers listen on every interface: the sweep connects on 127.0.0.1.)"""
    pytest.importorskip("ray", reason="the ray extra is installed by the README's test command")
    hidden = tmp_path_factory.mktemp("hidden")
    temp = Path(tempfile.mkdtemp(prefix="ray-"))  # short: Ray's socket paths live under it
    port = _free_port()
    command = [
        *(str(Path(sys.executable).parent / "ray"), "start", "--head", "--block"),
        *("--port", str(port), "--num-cpus", "2", "--num-gpus", "0"),
        *("--object-store-memory", "200000000", "--include-dashboard", "false", "--disable-usage-stats"),
        *("--temp-dir", str(temp)),
    ]
    namespaced = _private_mounts()
    if namespaced:
        hide = 'mount -t tmpfs tmpfs "$0" && exec "$@"'
        command = ["unshare", "--mount", "--propagation", "private", "sh", "-c", hide, str(hidden), *command]
    paths = [str(Path(snapflow.__file__).resolve().parents[1]), str(ROOT), os.environ.get("PYTHONPATH", "")]
    log = temp / "head.log"
    with open(log, "w") as output:
        head = subprocess.Popen(
            command,
            stdout=output,
            stderr=subprocess.STDOUT,
            env={**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, paths))},
            start_new_session=True,
        )
    try:
        deadline = time.monotonic() + 180
        while "Ray runtime started" not in log.read_text():
            assert head.poll() is None and time.monotonic() < deadline, (
                f"the Ray head did not start:\n{log.read_text()}"
            )
            time.sleep(0.5)
        yield RayHead(f"127.0.0.1:{port}", hidden if namespaced else None)
    finally:
        head.send_signal(signal.SIGTERM)  # ray start --block drains the node and stops what it started
        try:
            head.wait(timeout=60)
        except subprocess.TimeoutExpired:
            pass
        _end_session(head.pid)
        shutil.rmtree(temp, ignore_errors=True)


def _sweep(folder: Path, *options: str) -> subprocess.CompletedProcess:
    """``snapflow sweep tiny.toml`` run from ``folder``, two jobs side by side on one thread each."""
    (folder / "tiny.toml").write_text(CONFIG)
    arguments = ["sweep", "tiny.toml", "--workers", "2", "--threads", "1", "--no-progress", *options]
    return subprocess.run([*SNAPFLOW, *arguments], cwd=folder, capture_output=True, text=True, timeout=900)


def _masked(value: object) -> object:
    """``value`` (a JSON document) with the values of :data:`MEASURED_KEYS` replaced, at any depth."""
    if isinstance(value, dict):
        return {key: "<measured>" if key in MEASURED_KEYS else _masked(item) for key, item in value.items()}
    if isinstance(value, list):
        return [_masked(item) for item in value]
    return value


def _masked_tables(text: str) -> str:
    """tables.md with its measured caption and its seconds-per-step column replaced."""
    lines, column = [], None
    for line in MEASURED_CAPTION.sub("wall time: <measured>", text).splitlines():
        cells = line.split("|")
        if not line.startswith("|"):
            column = None
        elif column is None:  # a table's header
            column = cells.index(MEASURED_COLUMN) if MEASURED_COLUMN in cells else -1
        elif column > 0 and not line.startswith("|---"):
            cells[column] = " <measured> "
        lines.append("|".join(cells))
    return "\n".join(lines)


def _content(path: Path) -> str | bytes:
    """What ``path`` holds, its measured wall times masked: JSON documents as JSON (key order kept), tables.md as
    text, anything else as bytes."""
    if path.suffix in (".json", ".jsonl"):
        documents = [json.loads(line) for line in path.read_text().splitlines()] if path.suffix == ".jsonl" else []
        return json.dumps(_masked(documents or json.loads(path.read_text())))
    return _masked_tables(path.read_text()) if path.name == "tables.md" else path.read_bytes()


def _files(folder: Path) -> dict[str, Path]:
    return {str(path.relative_to(folder)): path for path in sorted(folder.rglob("*")) if path.is_file()}


# ~3 min on two cores: the tiny sweep (collection, a teacher, a student, two evaluations) twice, locally and on Ray
@pytest.mark.slow
def test_a_sweep_on_ray_writes_the_local_runners_records_tables_and_cache_byte_for_byte(ray_head, tmp_path):
    local, on_ray = tmp_path / "local", tmp_path / "ray"
    local.mkdir(), on_ray.mkdir()
    started = time.perf_counter()
    ran = _sweep(local)
    assert ran.returncode == 0, ran.stderr
    locally = time.perf_counter() - started
    ran_on_ray = _sweep(on_ray, "--backend", "ray", "--address", ray_head.address)
    log = ran_on_ray.stdout + ran_on_ray.stderr
    print(f"{log}\nlocal runner {locally:.0f} s, on Ray {time.perf_counter() - started - locally:.0f} s")  # pytest -s
    assert ran_on_ray.returncode == 0, log
    assert "Ray: 1 node(s), 2 CPUs, 0 GPUs; each job reserves 1 CPU(s)" in log
    assert log.count("done in") == 7, "two collections, the data, two runs, two evaluations"
    expected, written = _files(local), _files(on_ray)
    assert sorted(expected) == sorted(written), "the same files"
    for name in ("results/records/teacher/seed-0/job.json", "results/tables.md", "results/headline.png"):
        assert name in expected
    assert any(name.endswith("policy.safetensors") for name in expected), "the cache: the runs' checkpoints"
    compared = [name for name in expected if Path(name).name != LOCK]
    # anything but JSON and tables.md (weights, optimiser states, demonstrations, plots) compared as raw bytes
    different = [name for name in compared if _content(expected[name]) != _content(written[name])]
    assert not different, f"written differently on Ray: {different}"
    raw = sum(expected[name].read_bytes() == written[name].read_bytes() for name in compared)
    print(f"{len(compared)} files compared: {raw} identical byte for byte, the rest but for their measured times")
    assert not list(on_ray.glob(".snapflow-shared-*")) and not list(on_ray.rglob(".snapflow-shared-*"))


# ~30 s: two short runs of log jobs, each connecting to the head
@pytest.mark.slow
def test_on_ray_a_failed_job_is_told_as_locally_and_the_jobs_running_beside_it_are_recorded(
    ray_head, tmp_path, monkeypatch
):
    from snapflow.jobs.ray_backend import RayBackend

    monkeypatch.chdir(tmp_path)  # the folder the tasks run from, as the CLI's is
    failing, running, later = (
        LogJob(tmp_path / "fails", 1, fail=True),
        SlowJob(tmp_path / "slow", 2),
        LogJob(tmp_path / "later", 3),
    )
    with pytest.raises(RuntimeError, match="failed on purpose"):  # the job's own error, as the local runner's
        run_jobs([failing, running, later], 2, False, threads=1, backend=RayBackend(ray_head.address))
    assert is_done(running), "what finished beside the failure is recorded: the same command does not run it again"
    assert not is_done(failing) and not (tmp_path / "later").exists(), "no job starts after a failure"
    assert read_record(running)["process"] != os.getpid() and read_record(running)["threads"] == 1
    killed = KilledJob(tmp_path / "killed", 4)
    with pytest.raises(SnapflowError, match=r"the worker running log 4 died \(killed, or out of memory\)"):
        run_jobs([killed], 1, False, threads=1, backend=RayBackend(ray_head.address))


@pytest.mark.slow
def test_a_node_that_does_not_see_the_sweeps_folder_is_refused_in_one_line_before_any_job(ray_head, tmp_path):
    if ray_head.hidden is None:
        pytest.skip("no private mount namespace here to hide a folder from the Ray node")
    output = ray_head.hidden / "runs"
    (tmp_path / "tiny.toml").write_text(CONFIG.replace('output_dir = "runs"', f'output_dir = "{output.as_posix()}"'))
    arguments = ["sweep", "tiny.toml", "--backend", "ray", "--address", ray_head.address, "--no-progress"]
    ran = subprocess.run([*SNAPFLOW, *arguments], cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert ran.returncode == 2, ran.stderr
    line = ran.stderr.strip().splitlines()[-1]
    print(ran.stderr)
    assert line.startswith("snapflow sweep: error: the Ray node ") and f"does not see {output} " in line
    assert "on a shared file system" in line and "Traceback" not in ran.stderr
    assert not (output / "collect").exists(), "no job started"
    assert not list(output.glob(".snapflow-shared-*")), "the marker is removed"


def _refusal(tmp_path: Path, *arguments: str, missing: str = "") -> str:
    """The one line ``snapflow sweep ARGUMENTS`` is refused with, run from ``tmp_path`` (``missing``: a module made
    unimportable, as if its extra were not installed)."""
    script = f"import sys\n{f'sys.modules[{missing!r}] = None' if missing else ''}\nfrom snapflow.cli import main\n"
    script += "sys.exit(main(sys.argv[1:]))\n"
    ran = subprocess.run(
        [sys.executable, "-c", script, "sweep", "tiny.toml", *arguments], cwd=tmp_path, capture_output=True, text=True
    )
    lines = ran.stderr.strip().splitlines()
    assert ran.returncode == 2 and len(lines) == 1, ran.stderr
    return lines[0]


def test_ray_is_an_extra_its_flags_are_refused_without_it_and_an_address_nobody_serves_in_one_line(tmp_path):
    (tmp_path / "tiny.toml").write_text(CONFIG)
    line = _refusal(tmp_path, "--backend", "ray", missing="ray")
    assert 'this needs ray, which is not installed: pip install "snapflow-vla[ray]"' in line
    assert "--address, --gpus-per-job: only for --backend ray" in _refusal(
        tmp_path, "--address", "127.0.0.1:1", "--gpus-per-job", "1"
    )
    pytest.importorskip("ray", reason="the ray extra is installed by the README's test command")
    line = _refusal(tmp_path, "--backend", "ray", "--address", f"127.0.0.1:{_free_port()}")
    assert line.startswith("snapflow sweep: error: no Ray cluster answers at --address 127.0.0.1:")
    assert not (tmp_path / "runs").exists(), "refused before anything was written"
