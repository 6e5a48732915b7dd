"""Fixtures of the LeRobot adapter tests: the tiny model folders the tiny policies read (written once a session)."""

from __future__ import annotations

import pytest


@pytest.fixture(scope="session")
def vlm_directory(tmp_path_factory):
    pytest.importorskip(
        "lerobot", reason="LeRobot is installed by the README's test command; this environment lacks it"
    )
    from tests.lerobot_tiny import write_tiny_smolvlm

    return write_tiny_smolvlm(tmp_path_factory.mktemp("tiny_smolvlm"))


@pytest.fixture(scope="session")
def clip_directory(tmp_path_factory, vlm_directory):
    """A one-layer CLIP for the tiny multi-task DiT, with the tiny SmolVLM's tokenizer beside it."""
    from tests.lerobot_tiny_multi_task_dit import write_tiny_clip

    return write_tiny_clip(tmp_path_factory.mktemp("clip") / "tiny-clip", tokenizer=vlm_directory)


@pytest.fixture(scope="session")
def groot_checkpoint(tmp_path_factory):
    """A random GR00T N1.7 checkpoint folder and the tiny Qwen3-VL folder it names, written once a session."""
    from importlib.metadata import version

    from packaging.version import Version

    from snapflow.adapters.lerobot.groot import GrootFlowPolicy

    minimum, installed = GrootFlowPolicy.minimum_lerobot, version("lerobot")
    if Version(installed) < Version(minimum):  # lerobot 0.4 / 0.5 ship GR00T N1.5, another model
        pytest.skip(f"LeRobot's GR00T N1.7 arrived in lerobot {minimum}; lerobot {installed} is installed")
    from tests.lerobot_tiny_groot import write_tiny_groot

    return write_tiny_groot(tmp_path_factory.mktemp("groot"))
