"""Checkpoints kept in git history, not the tree: ``snapflow checkpoints archive`` / ``restore`` / ``list`` run as a
user runs them, on a repository the test makes, and the repository's own manifest checked against its history."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from snapflow.reporting.archive import MANIFEST, git_blob_id, read_manifest

REPOSITORY = Path(__file__).resolve().parents[2]
CHECKPOINT = "docs/results/sweeps/demo/records/teacher/seed-0/checkpoint/step_0000010"
SNAPFLOW = [str(Path(sys.executable).with_name("snapflow"))]  # the command a user types


def git(root: Path, *arguments: str) -> str:
    return subprocess.run(["git", *arguments], cwd=root, check=True, capture_output=True, text=True).stdout


def snapflow(root: Path, *arguments: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([*SNAPFLOW, *arguments], cwd=root, capture_output=True, text=True, env=os.environ)


@pytest.fixture
def repository(tmp_path: Path) -> Path:
    """A git repository with the project's ignore rules, one committed file and a checkpoint written since."""
    root = tmp_path / "repository"
    root.mkdir()
    git(root, "init", "-q", "-b", "main")
    git(root, "config", "user.email", "tests@example.com")
    git(root, "config", "user.name", "tests")
    git(root, "config", "uploadpack.allowFilter", "true")  # serve blob-less clones, as a hosting service does
    (root / ".gitignore").write_text((REPOSITORY / ".gitignore").read_text())
    (root / "README.md").write_text("a project\n")
    git(root, "add", ".")
    git(root, "commit", "-q", "-m", "start")
    (root / CHECKPOINT).mkdir(parents=True)
    (root / CHECKPOINT / "policy.safetensors").write_bytes(os.urandom(4096))
    (root / CHECKPOINT / "policy.json").write_text("{}\n")
    git(root, "add", ".")  # the checkpoint's small files are committed as usual; its weights are ignored
    git(root, "commit", "-q", "-m", "a teacher's record")
    return root


def test_archive_then_restore_brings_back_the_same_bytes(repository: Path) -> None:
    weights = repository / CHECKPOINT / "policy.safetensors"
    original = weights.read_bytes()
    (repository / "notes.txt").write_text("a change of the user's, not to be committed\n")
    git(repository, "add", "notes.txt")

    result = snapflow(repository, "checkpoints", "archive", "-m", "Teacher seed 0")
    assert result.returncode == 0, result.stderr
    assert "archived 1 file(s)" in result.stdout

    # two commits: the first holds the weights, the second removes them and names the first in the manifest
    assert git(repository, "log", "--format=%s", "-3").splitlines()[1] == "Teacher seed 0"
    assert git(repository, "ls-tree", "-r", "--name-only", "HEAD~1").count("policy.safetensors") == 1
    assert "policy.safetensors" not in git(repository, "ls-tree", "-r", "--name-only", "HEAD")
    (entry,) = read_manifest(repository)
    assert entry.path == f"{CHECKPOINT}/policy.safetensors"
    assert entry.commit == git(repository, "rev-parse", "HEAD~1").strip()
    assert entry.blob == git_blob_id(original) and entry.bytes == len(original)
    # the user's staged change is still staged and uncommitted; the weights stay on disk, ignored
    assert git(repository, "status", "--porcelain").splitlines() == ["A  notes.txt"]
    assert weights.read_bytes() == original
    assert "nothing to archive" in snapflow(repository, "checkpoints", "archive").stdout

    # a fresh clone of main has no weights until they are restored, then the same bytes
    clone = repository.parent / "clone"
    git(repository.parent, "clone", "-q", "--filter=blob:none", f"file://{repository}", str(clone))
    assert not (clone / CHECKPOINT / "policy.safetensors").exists()
    missing = git(clone, "rev-list", "--objects", "--missing=print", "--all").splitlines()
    assert f"?{entry.blob}" in missing  # the clone did not download the weights
    assert "archived" in snapflow(clone, "checkpoints", "list").stdout
    result = snapflow(clone, "checkpoints", "restore", CHECKPOINT)
    assert result.returncode == 0, result.stderr
    assert "restored 1 file(s)" in result.stdout
    assert (clone / CHECKPOINT / "policy.safetensors").read_bytes() == original
    assert git(clone, "status", "--porcelain") == ""  # restored files are ignored: they never travel by accident
    assert "0 file(s) (0.0 MB); 1 already in place" in snapflow(clone, "checkpoints", "restore").stdout


def test_a_changed_checkpoint_is_archived_again_and_restore_repairs_a_damaged_file(repository: Path) -> None:
    weights = repository / CHECKPOINT / "policy.safetensors"
    assert snapflow(repository, "checkpoints", "archive").returncode == 0
    first = read_manifest(repository)[0]
    weights.write_bytes(os.urandom(2048))  # training went on: the kept checkpoint changed
    assert "archived 1 file(s)" in snapflow(repository, "checkpoints", "archive").stdout
    second = read_manifest(repository)[0]
    assert second.commit != first.commit and second.bytes == 2048

    weights.write_bytes(b"half-written")
    assert snapflow(repository, "checkpoints", "restore").returncode == 0
    assert git_blob_id(weights.read_bytes()) == second.blob


def test_refusals_are_one_line(repository: Path) -> None:
    result = snapflow(repository, "checkpoints", "restore", "docs/results/nothing-here")
    assert result.returncode == 2
    assert result.stderr.strip() == (
        "snapflow checkpoints: error: nothing archived at or under docs/results/nothing-here "
        "(see `snapflow checkpoints list`)"
    )
    (repository / MANIFEST).parent.mkdir(parents=True, exist_ok=True)
    (repository / MANIFEST).write_text("{not json")
    result = snapflow(repository, "checkpoints", "list")
    assert result.returncode == 2 and "archive.json is corrupt" in result.stderr and "Traceback" not in result.stderr
    outside = repository.parent / "not-a-repository"
    outside.mkdir()
    result = snapflow(outside, "checkpoints", "list")
    assert result.returncode == 2 and "not a git repository" in result.stderr


def test_a_missing_archived_weight_names_the_restore_command(repository: Path) -> None:
    """Opening a checkpoint whose weights are archived, not restored, says which command brings them back."""
    from snapflow.policies.checkpoint import CheckpointError, read_tensors

    assert snapflow(repository, "checkpoints", "archive").returncode == 0
    (repository / CHECKPOINT / "policy.safetensors").unlink()
    with pytest.raises(CheckpointError, match=f"`snapflow checkpoints restore {CHECKPOINT}/policy.safetensors`"):
        read_tensors(repository / CHECKPOINT / "policy.safetensors")


def test_a_sweep_never_trains_again_what_history_keeps(repository: Path) -> None:
    """A kept checkpoint whose weights are archived but not restored stops the runner with the restore command,
    where reading it as absent would train the run again from scratch; restored, it is found where it was."""
    from snapflow.training.checkpoint import KEPT, read_kept

    kept = repository / CHECKPOINT
    (kept.parent / KEPT).write_text(json.dumps({"checkpoint": kept.name, "finished": True}))
    assert snapflow(repository, "checkpoints", "archive").returncode == 0
    (kept / "policy.safetensors").unlink()
    with pytest.raises(FileNotFoundError, match=f"lacks its weights; .*`snapflow checkpoints restore {CHECKPOINT}"):
        read_kept(kept.parent)
    assert snapflow(repository, "checkpoints", "restore").returncode == 0
    assert read_kept(kept.parent) == (kept, {"finished": True})


def test_a_kept_lerobot_train_step_reads_with_its_weights_one_folder_down(repository: Path) -> None:
    """A lerobot-train step kept for another machine holds its weights in ``pretrained_model/``: in place, it is
    found; archived and not restored, it names the restore command."""
    from snapflow.training.checkpoint import KEPT, read_kept

    step = repository / CHECKPOINT.replace("step_0000010", "step_000500")
    (step / "pretrained_model").mkdir(parents=True)
    (step / "pretrained_model" / "model.safetensors").write_bytes(os.urandom(4096))
    (step.parent / KEPT).write_text(json.dumps({"checkpoint": step.name, "run": {"flags": []}}))
    assert snapflow(repository, "checkpoints", "archive").returncode == 0
    assert read_kept(step.parent) == (step, {"run": {"flags": []}}), "its weights are there, one folder down"
    (step / "pretrained_model" / "model.safetensors").unlink()
    with pytest.raises(FileNotFoundError, match="lacks its weights"):
        read_kept(step.parent)


def test_the_repository_manifest_names_blobs_its_history_holds() -> None:
    """Every archived checkpoint of this repository is in main's history at the commit and path named, and none is
    in the tree."""
    if git(REPOSITORY, "rev-parse", "--is-shallow-repository").strip() == "true":
        pytest.skip("a shallow clone lacks the history the archive reads")
    entries = read_manifest(REPOSITORY)
    assert entries, f"{MANIFEST} lists no checkpoint"
    for entry in entries:
        assert git(REPOSITORY, "rev-parse", f"{entry.commit}:{entry.path}").strip() == entry.blob
    assert git(REPOSITORY, "ls-files", "*.safetensors") == ""
    assert json.loads((REPOSITORY / MANIFEST).read_text())["files"] == sorted(
        json.loads((REPOSITORY / MANIFEST).read_text())["files"], key=lambda entry: entry["path"]
    )


def test_kept_progress_that_moved_on_leaves_the_manifest_and_history_keeps_it(repository: Path) -> None:
    """A run's kept progress moves to a later checkpoint folder (the trainer removes the earlier one): the next
    archive names the new weights and drops the old folder's, whose commit still holds them."""
    import shutil

    assert snapflow(repository, "checkpoints", "archive").returncode == 0
    (first,) = read_manifest(repository)
    later = CHECKPOINT.replace("step_0000010", "step_0000020")
    shutil.rmtree(repository / CHECKPOINT)
    (repository / later).mkdir()
    (repository / later / "policy.safetensors").write_bytes(os.urandom(1024))
    (repository / later / "policy.json").write_text("{}\n")

    result = snapflow(repository, "checkpoints", "archive", "-m", "Teacher at step 20")
    assert result.returncode == 0, result.stderr
    assert f"dropped from {MANIFEST}, their folders gone (their weights stay in history): {first.path}" in result.stdout
    (entry,) = read_manifest(repository)
    assert entry.path == f"{later}/policy.safetensors"
    assert git(repository, "rev-parse", f"{first.commit}:{first.path}").strip() == first.blob
