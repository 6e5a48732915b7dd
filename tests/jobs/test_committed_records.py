"""The committed sweeps stay valid through every refactor: each job whose record is committed in its ledger still
holds it (its settings and its dependencies' keys, byte for byte as JSON reads them), and a few cache keys, of
sweeps whose outputs are cached but not committed, are what they were (a changed key means work done again)."""

from __future__ import annotations

from pathlib import Path

import pytest

from snapflow.jobs.runner import holds_record_of
from snapflow.jobs.sweep.planning import jobs
from snapflow.jobs.sweep.schema import load_sweep

ROOT = Path(__file__).resolve().parents[2]
SWEEPS = sorted((ROOT / "configs" / "sweeps").glob("*.toml"))

#: keys computed at 2026-12-05 (c1d8eeb, and again after the day's changes): a job's settings and dependencies
KEYS = {
    ("mt10-state", "mt10-state: train teacher seed 0"): "9e68c043ad1a112d",
    ("smolvla-libero-spatial-dart", "smolvla-libero-spatial-dart: train teacher seed 0"): "ac13a9b2ebf5428c",
    ("smolvla-libero-spatial-dart", "smolvla-libero-spatial-dart: train lerobot-train seed 0"): "37cadb4fb8a27d70",
    (
        "smolvla-libero-spatial-dart",
        "smolvla-libero-spatial-dart: evaluate teacher seed 0 (naive-1; n_act 4)",
    ): "b308cc317b9ff2e2",
}


@pytest.mark.slow  # loading a sweep makes its benchmark: the simulators import
@pytest.mark.parametrize("path", SWEEPS, ids=[path.stem for path in SWEEPS])
def test_every_committed_record_of_a_sweep_is_still_its_jobs(path, monkeypatch):
    monkeypatch.chdir(ROOT)  # a sweep's output and results folders are read from the working directory
    planned = jobs(load_sweep(path))
    ledgers = [job for job in planned if job.ledger_path is not None and job.ledger_path.is_file()]
    stale = [job.describe() for job in ledgers if not holds_record_of(job.ledger_path, job)]
    assert not stale, f"committed records no job of today's code holds: {stale}"
    keys = {job.describe(): job.key for job in planned}
    held = {described: key for (sweep, described), key in KEYS.items() if sweep == path.stem}
    assert {described: keys.get(described) for described in held} == held


def test_the_keys_held_name_jobs_of_committed_sweeps():
    assert {name for name, _ in KEYS} <= {path.stem for path in SWEEPS}
