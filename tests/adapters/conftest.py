"""Fixtures of the LeRobot adapter tests: the tiny SmolVLM folder every tiny SmolVLA reads (written once a session)."""

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
