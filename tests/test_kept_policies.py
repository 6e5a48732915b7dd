"""Everything the repository keeps reopens on a fresh clone: each policy folder whose weights ``docs/results/archive.json``
names is restored from history into a temporary folder, away from any output of the machine that trained it, and
``open_policy`` must open it and sample one chunk through its own processors; the committed files name no absolute
path of the machine that wrote them."""

from __future__ import annotations

import json
import re
import shutil
import subprocess
from pathlib import Path, PurePosixPath

import numpy as np
import pytest
import torch

from snapflow.flow.modes import NAIVE_1, SNAPFLOW_1
from snapflow.flow.solver import sample_actions
from snapflow.policies.loaded import CheckpointError
from snapflow.reporting.archive import read_manifest, repository_root, restore
from snapflow.reporting.packed import PACKED_SUFFIX
from snapflow.sources import LEROBOT_RUN_FORMAT, open_policy
from snapflow.training.checkpoint import STEP_PREFIX

ROOT = repository_root(Path(__file__))
#: a string value that starts with an absolute path of a machine: what a committed file must never hold
MACHINE_PATH = re.compile(r'"/(home|root|tmp|work|usr|opt)/')


def _tracked(*pathspecs: str) -> list[str]:
    listing = subprocess.run(["git", "ls-files", "-z", "--", *pathspecs], cwd=ROOT, capture_output=True, check=True)
    return [path for path in listing.stdout.decode().split("\0") if path]


#: what a folder of archived weights is: a policy (what opens), a LeRobot run's training checkpoint (what resumes
#: training, and must be refused naming the policy folder), or part of an unfinished lerobot-train run's kept progress
#: (its policy folder and training state, what lerobot-train resumes from: ``training/lerobot_progress.py``)
POLICY, RUN_CHECKPOINT, LEROBOT_TRAIN_PROGRESS = "policy", "run checkpoint", "lerobot-train progress"


def _kept_folders() -> dict[str, str]:
    """Each folder that archived weights live in, and what it is."""
    folders = {}
    for entry in read_manifest(ROOT):
        if entry.path.endswith(PACKED_SUFFIX):  # a sweep's kept collection, not weights
            continue
        folder = PurePosixPath(entry.path).parent
        if folder.parent.name.startswith(STEP_PREFIX) and folder.name in ("pretrained_model", "training_state"):
            folders[str(folder)] = LEROBOT_TRAIN_PROGRESS
        elif (ROOT / folder / "config.json").is_file():
            folders[str(folder)] = POLICY
        elif (ROOT / folder / "policy.json").is_file():
            run = json.loads((ROOT / folder / "policy.json").read_text())["format"] == LEROBOT_RUN_FORMAT
            folders[str(folder)] = RUN_CHECKPOINT if run else POLICY
    return folders


KEPT = _kept_folders()


def _lerobot_opens(folder: Path) -> bool:
    """Whether this environment's LeRobot can open the LeRobot folder (the student types need lerobot >= 0.5)."""
    if not (folder / "config.json").is_file():
        return True
    pytest.importorskip("lerobot")
    from snapflow.adapters.lerobot_types import lerobot_loads_plugins

    return lerobot_loads_plugins()


@pytest.fixture(scope="module")
def fresh_copies(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The tracked files of every kept folder and their archived weights, restored from history, in a folder of
    their own (as a fresh clone has them after ``snapflow checkpoints restore``)."""
    shallow = subprocess.run(["git", "rev-parse", "--is-shallow-repository"], cwd=ROOT, capture_output=True, text=True)
    if shallow.stdout.strip() == "true":
        pytest.skip("a shallow clone lacks the history the weights are archived in (git fetch --unshallow)")
    into = tmp_path_factory.mktemp("clone")
    for path in _tracked(*KEPT):
        (into / path).parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(ROOT / path, into / path)
    restore(ROOT, [entry for entry in read_manifest(ROOT) if str(PurePosixPath(entry.path).parent) in KEPT], into)
    return into


#: the sweeps' kept collections: one packed task each, beside its collection record
PACKS = [entry for entry in read_manifest(ROOT) if entry.path.endswith(PACKED_SUFFIX)]


def test_every_archived_weight_belongs_to_a_kept_folder() -> None:
    weights = [entry for entry in read_manifest(ROOT) if entry not in PACKS]
    stray = [entry.path for entry in weights if str(PurePosixPath(entry.path).parent) not in KEPT]
    assert not stray, f"archived weights in no policy or checkpoint folder: {stray}"
    # the MiniVLA LIBERO teachers and students, and every SmolVLA seed's
    assert sum(kind == POLICY for kind in KEPT.values()) >= 18


@pytest.mark.lerobot
@pytest.mark.parametrize("folder", sorted(folder for folder, kind in KEPT.items() if kind == POLICY))
def test_a_kept_policy_opens_on_a_fresh_clone_and_samples_a_chunk(fresh_copies: Path, folder: str) -> None:
    path = fresh_copies / folder
    if not _lerobot_opens(path):
        pytest.skip("a LeRobot student type: lerobot >= 0.5 opens it")
    opened = open_policy(path)
    processor = opened.processor
    size = processor.image_size
    images = None if size is None else np.full((1, size, size, 3), 128, dtype=np.uint8)
    extra = {name: np.full((1, size, size, 3), 128, dtype=np.uint8) for name in processor.extra_cameras}
    observation = processor.observation(
        np.zeros((1, processor.state_dim), dtype=np.float32), ["pick up the black bowl"], images, extra
    )
    noise = torch.randn(1, processor.chunk_length, processor.action_dim, generator=torch.Generator().manual_seed(0))
    with torch.no_grad():
        chunk = processor.unnormalize_actions(
            sample_actions(opened.policy.eval(), observation, noise, SNAPFLOW_1 if opened.distilled else NAIVE_1)
        )
    assert chunk.shape == (1, processor.chunk_length, processor.action_dim)
    assert torch.isfinite(chunk).all()


@pytest.mark.parametrize("entry", PACKS, ids=[PurePosixPath(entry.path).parent.name for entry in PACKS])
def test_a_kept_collection_comes_back_whole_and_is_the_one_its_record_names(tmp_path: Path, entry) -> None:
    """A packed task of a sweep restores from history and unpacks to demonstrations and their video part, made by
    the collection job its committed record describes (what a sweep on a fresh clone checks before using it)."""
    from snapflow.data.demonstrations import Demonstrations
    from snapflow.reporting.packed import unpack_folder

    shallow = subprocess.run(["git", "rev-parse", "--is-shallow-repository"], cwd=ROOT, capture_output=True, text=True)
    if shallow.stdout.strip() == "true":
        pytest.skip("a shallow clone lacks the history the packs are archived in (git fetch --unshallow)")
    restore(ROOT, [entry], tmp_path)
    record = json.loads((ROOT / PurePosixPath(entry.path).parent / "job.json").read_text())
    folder = unpack_folder(tmp_path / entry.path, tmp_path / "collection")
    assert json.loads((folder / "collected.json").read_text())["config"] == record["config"]
    demonstrations = Demonstrations.load(folder)
    assert len(demonstrations.episodes) == record["config"]["episodes_per_task"] and demonstrations.images is None
    assert (folder / "lerobot" / "meta" / "info.json").is_file(), "the frames travel as the task's video part"


@pytest.mark.parametrize("folder", sorted(folder for folder, kind in KEPT.items() if kind == RUN_CHECKPOINT))
def test_a_kept_training_checkpoint_is_refused_naming_what_to_pass(folder: str) -> None:
    with pytest.raises(CheckpointError, match="training checkpoint of a LeRobot policy.*pass") as refusal:
        open_policy(ROOT / folder)
    assert "\n" not in str(refusal.value)


@pytest.mark.parametrize(
    "folder",
    sorted({str(PurePosixPath(folder).parent) for folder, kind in KEPT.items() if kind == LEROBOT_TRAIN_PROGRESS}),
)
def test_kept_lerobot_train_progress_is_whole_and_names_its_run_not_a_machine(folder: str) -> None:
    """What a fresh clone's lerobot-train resumes from: the policy folder and the training state of one step, noted
    in the kept folder as the progress of a run (only the same run resumes it), its student named by a placeholder."""
    note = json.loads((ROOT / folder).with_name("kept.json").read_text())
    assert note["checkpoint"] == PurePosixPath(folder).name and set(note["run"]) == {"flags", "distill", "weights"}
    assert (ROOT / folder / "training_state" / "training_step.json").is_file()
    config = (ROOT / folder / "pretrained_model" / "config.json").read_text()
    assert not MACHINE_PATH.search(config)


def test_no_committed_record_or_config_names_a_path_of_the_machine_that_wrote_it() -> None:
    named = [
        f"{path}:{number}"
        for path in _tracked("docs", "configs")
        if not path.endswith((".png", ".safetensors"))
        for number, line in enumerate((ROOT / path).read_text(errors="replace").splitlines(), start=1)
        if MACHINE_PATH.search(line)
    ]
    assert not named, f"absolute paths of a machine in: {named[:10]}"
