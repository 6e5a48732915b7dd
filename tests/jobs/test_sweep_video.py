"""A sweep's demonstrations kept as video (``[data] video``): each task's collection is its part of the LeRobotDataset,
its frames encoded once by LeRobot's writer, packed beside the sweep's records and archived in git history as soon as
it is collected; a fresh clone restores them and collects nothing (fast: the settings; slow: a real collection)."""

from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from snapflow.adapters.lerobot_types import lerobot_loads_plugins
from snapflow.cli import main
from snapflow.data.demonstrations import Demonstrations
from snapflow.jobs.sweep import load_sweep
from snapflow.jobs.sweep.data_jobs import PACKED, PART, held_out_with_frames
from snapflow.jobs.sweep.planning import data_job, train_job
from tests.reporting.test_archive import REPOSITORY, SNAPFLOW, git

TASKS = ("reach-v3", "button-press-topdown-v3")


def write_config(directory: Path, data: str = "image_size = 32\nvideo = { gop = 16 }", runs: str = "") -> Path:
    """A two-task Meta-World sweep whose results live under ``directory``'s ``docs/results`` (where the archive keeps
    what it archives) and whose outputs under ``outputs``."""
    path = directory / "video.toml"
    path.write_text(f"""
name = "video"
output_dir = "outputs/sweeps/video"
results_dir = "docs/results/sweeps/video"

[data]
tasks = {json.dumps(list(TASKS))}
episodes_per_task = 2
{data}

[runs.teacher]
lerobot = {{ smolvlm = "tiny", image_size = 32, chunk_size = 4, n_action_steps = 2 }}
{runs}
[[tables]]
name = "headline"
rows = [{{ label = "teacher 10-NFE", run = "teacher", mode = "teacher-10" }}]
""")
    return path


@pytest.mark.parametrize(
    ("data", "runs", "message"),
    [
        (
            'image_size = 32\nvideo = { codec = "mpeg2" }',
            "",
            "[data] video: codec one of ['libsvtav1', 'h264', 'hevc']",
        ),
        ("video = {}", "", "and an image_size, needed"),
        ("image_size = 32\nvideo = { keyframes = 2 }", "", "[data] video: unknown key(s) ['keyframes']"),
        (
            "image_size = 32\nvideo = {}",
            "[runs.built-in]\n",
            "[runs.built-in]: a built-in policy cannot read [data] video frames",
        ),
    ],
)
def test_video_frames_are_refused_where_they_cannot_be_stored_or_read(tmp_path, capsys, data, runs, message):
    path = write_config(tmp_path, data, runs)
    assert main(["sweep", str(path), "--report-only", "--no-progress"]) == 2
    error = capsys.readouterr().err
    assert message in error and "Traceback" not in error


def test_only_a_video_collection_is_kept_beside_the_records_and_the_setting_keeps_old_keys(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    video = data_job(load_sweep(write_config(tmp_path)))
    images = data_job(load_sweep(write_config(tmp_path, "image_size = 32")))
    part = video.parts[0]
    assert part.ledger == Path("docs/results/sweeps/video/records/collect/reach-v3/job.json")
    assert part.packed == part.ledger.parent / PACKED
    assert all(job.ledger is None and job.packed is None for job in images.parts)
    assert "video" not in images.parts[0].settings(), "a sweep without video keeps the keys it had"
    assert part.settings()["video"] == {"codec": "libsvtav1", "gop": 16, "crf": 30, "preset": 4}
    assert part.key != images.parts[0].key


def decoded_dataset(root: Path) -> dict[str, np.ndarray]:
    """Every frame of each video feature of the LeRobotDataset at ``root``, decoded in order."""
    from snapflow.adapters.lerobot.video import decoded_frames

    features = sorted(path.name for path in (root / "videos").iterdir())
    assert features, f"no video in {root}"
    return {feature: decoded_frames(root, feature) for feature in features}


def training_frames(root: Path, feature: str) -> np.ndarray:
    """The frames of ``feature`` that training reads from the runs' LeRobotDataset at ``root``, as uint8 HWC."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    dataset = LeRobotDataset("local/lerobot", root=root)
    frames = [(dataset[index][feature] * 255).round().byte().permute(1, 2, 0).numpy() for index in range(len(dataset))]
    return np.stack(frames)


# ~60 s on CI's two cores: two tasks of two episodes collected with 32-px frames, encoded, kept, archived, then on a
# "fresh clone" restored from history and joined again without a collection.
@pytest.mark.slow
@pytest.mark.lerobot
@pytest.mark.skipif(not lerobot_loads_plugins(), reason="a chosen video encoding needs LeRobot >= 0.5")
def test_a_fresh_clone_restores_the_kept_collections_and_collects_nothing(tmp_path, monkeypatch):
    from snapflow.jobs.runner import run_jobs
    from snapflow.jobs.sweep import data_jobs

    root = tmp_path / "repository"
    root.mkdir()
    for arguments in (("init", "-q", "-b", "main"), ("config", "user.email", "t@e.st"), ("config", "user.name", "t")):
        git(root, *arguments)
    shutil.copy(REPOSITORY / ".gitignore", root / ".gitignore")
    config_path = write_config(root)
    monkeypatch.chdir(root)
    config = load_sweep(config_path)
    dataset = train_job(config, "teacher", 0).dataset
    assert dataset is not None
    run_jobs([dataset], progress=False)

    records = root / "docs/results/sweeps/video/records/collect"
    kept = [decoded_dataset(config.collect_dir(task) / PART) for task in TASKS]
    (camera,) = kept[0]
    trained_on = training_frames(dataset.directory, camera)
    assert np.array_equal(trained_on, np.concatenate([frames[camera] for frames in kept])), "the kept frames, as PNG"
    # the offline metrics' held-out episodes: the whole set's split, with their kept frames decoded
    whole = Demonstrations.load(dataset.data.directory)
    held_out = Demonstrations.load(held_out_with_frames(dataset.data, 0.5))
    _, val = whole.split(0.5)
    assert [(e.task, e.variation) for e in held_out.episodes] == [
        (whole.episodes[e].task, whole.episodes[e].variation) for e in val
    ]
    assert np.array_equal(held_out.actions, whole.actions[whole.rows(val)])
    assert np.array_equal(held_out.images, np.concatenate([frames[camera] for frames in kept])[whole.rows(val)])
    for task in TASKS:
        record = json.loads((records / task / "job.json").read_text())
        (error,) = record["frame_error"].values()
        assert 0 < error["mean_abs_error"] < 8 and error["psnr_db"] > 25, "lossy, and close to the rendered frames"
        assert record["packed_bytes"] == (records / task / PACKED).stat().st_size

    # kept in history as soon as collected: the records committed, the packs archived (and out of the tree)
    git(root, "add", ".")
    git(root, "commit", "-q", "-m", "the sweep's records")
    archived = subprocess.run([*SNAPFLOW, "checkpoints", "archive", "-m", "collected"], cwd=root, text=True)
    assert archived.returncode == 0
    assert not git(root, "ls-files", "--", "*.tar"), "the packs live in history, not the tree"

    # a fresh clone: no outputs, no packs on disk; the sweep restores them and collects nothing
    shutil.rmtree(root / "outputs")
    for task in TASKS:
        (records / task / PACKED).unlink()

    def no_collection(*args, **kwargs):
        raise AssertionError("a kept task was collected again")

    monkeypatch.setattr(data_jobs, "collect", no_collection)
    assert set(run_jobs([dataset], progress=False)) == {
        "video: demonstrations of 2 tasks",
        "video: demonstrations as a LeRobotDataset",
    }
    assert all((records / task / PACKED).is_file() for task in TASKS), "restored from history"
    assert all(
        np.array_equal(decoded_dataset(config.collect_dir(task) / PART)[camera], frames[camera])
        for task, frames in zip(TASKS, kept, strict=True)
    ), "the restored frames decode equal to the kept ones"
    assert np.array_equal(training_frames(dataset.directory, camera), trained_on), "and the runs train on the same"
