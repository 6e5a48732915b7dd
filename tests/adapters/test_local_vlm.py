"""A SmolVLA over a SmolVLM written locally, moved to another machine: its folder carries the SmolVLM and names it
relative to itself, so that it opens, samples the same chunk and runs in LeRobot's own tools where the folder that it
was trained beside is gone."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import torch

from snapflow.adapters.lerobot.local_vlm import BUNDLED_VLM, bundle_vlm, bundled_vlm
from snapflow.flow.modes import SNAPFLOW_1
from snapflow.policies.loaded import CheckpointError
from snapflow.sources import open_policy
from tests.lerobot_tiny import save_tiny_student, tiny_batch, write_tiny_smolvlm


def _chunk(folder: Path) -> torch.Tensor:
    opened = open_policy(folder)
    batch = tiny_batch(batch_size=1)
    observation = opened.processor.observation(
        batch["observation.state"].numpy()[:, :4],
        ["pick the red cube"],
        (batch["observation.images.top"].permute(0, 2, 3, 1) * 255).to(torch.uint8).numpy(),
    )
    noise = torch.randn(1, 4, 4, generator=torch.Generator().manual_seed(0))
    from snapflow.flow.solver import sample_actions

    with torch.no_grad():
        return sample_actions(opened.policy.eval(), observation, noise, SNAPFLOW_1)


def test_a_bundled_folder_opens_where_its_smolvlm_was_deleted_and_samples_the_same_chunk(tmp_path: Path) -> None:
    vlm = write_tiny_smolvlm(tmp_path / "machine-a" / "smolvlm").resolve()
    trained = save_tiny_student(
        vlm, tmp_path / "machine-a" / "policy", image_key="observation.images.top", image_size=64
    )
    before = _chunk(trained)

    assert bundle_vlm(trained) and not bundle_vlm(trained)  # the second time: inside already
    moved = shutil.copytree(trained, tmp_path / "machine-b" / "policy")
    shutil.rmtree(tmp_path / "machine-a")

    assert json.loads((moved / "config.json").read_text())["vlm_model_name"] == BUNDLED_VLM
    steps = json.loads((moved / "policy_preprocessor.json").read_text())["steps"]
    # a student's tokenizer step carries the tokenizer (tests/adapters/test_lerobot_tools_anywhere.py): no name
    assert not any("tokenizer_name" in step["config"] for step in steps)
    assert bundled_vlm(moved) == (moved / BUNDLED_VLM).resolve()
    torch.testing.assert_close(_chunk(moved), before, rtol=0, atol=0)


def test_a_folder_copied_without_its_smolvlm_is_refused_naming_what_it_lacks(tmp_path: Path) -> None:
    folder = tmp_path / "policy"
    folder.mkdir()
    (folder / "config.json").write_text(json.dumps({"type": "smolvla", "vlm_model_name": BUNDLED_VLM}))
    with pytest.raises(CheckpointError, match=f"names its VLM {BUNDLED_VLM}/, which the folder lacks"):
        bundled_vlm(folder)


def test_a_hub_model_is_left_as_named(tmp_path: Path) -> None:
    folder = tmp_path / "policy"
    folder.mkdir()
    (folder / "config.json").write_text(json.dumps({"type": "smolvla", "vlm_model_name": "HuggingFaceTB/SmolVLM2"}))
    assert bundled_vlm(folder) is None and not bundle_vlm(folder)


def test_lerobot_reads_a_bundled_folder_from_inside_it(tmp_path: Path) -> None:
    """As snapflow runs lerobot-eval on such a folder: LeRobot's own loaders, in a process started in the folder."""
    vlm = write_tiny_smolvlm(tmp_path / "gone").resolve()
    folder = save_tiny_student(vlm, tmp_path / "policy", image_key="observation.images.top", image_size=64)
    bundle_vlm(folder)
    shutil.rmtree(tmp_path / "gone")
    script = (
        "import snapflow.adapters.lerobot.plugin\n"
        "from lerobot.configs.policies import PreTrainedConfig\n"
        "from lerobot.policies.factory import make_pre_post_processors\n"
        "config = PreTrainedConfig.from_pretrained('.')\n"
        "pre, _ = make_pre_post_processors(config, pretrained_path='.')\n"
        "print(len(pre.steps))\n"
    )
    done = subprocess.run([sys.executable, "-c", script], cwd=folder, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr[-2000:]
