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


def skip_unless_lerobot_has(adapter: str, model: str) -> None:
    """Skip where the installed LeRobot predates the adapter's policy type (``adapter``: ``"module:Class"`` under
    ``snapflow.adapters.lerobot``, its ``minimum_lerobot``)."""
    from importlib import import_module
    from importlib.metadata import version

    from packaging.version import Version

    module, name = adapter.split(":")
    minimum = getattr(import_module(f"snapflow.adapters.lerobot.{module}"), name).minimum_lerobot
    installed = version("lerobot")
    if Version(installed) < Version(minimum):  # e.g. lerobot 0.4 / 0.5 ship GR00T N1.5, another model
        pytest.skip(f"LeRobot's {model} arrived in lerobot {minimum}; lerobot {installed} is installed")


@pytest.fixture(scope="session")
def groot_checkpoint(tmp_path_factory):
    """A random GR00T N1.7 checkpoint folder and the tiny Qwen3-VL folder it names, written once a session."""
    skip_unless_lerobot_has("groot:GrootFlowPolicy", "GR00T N1.7")
    from tests.lerobot_tiny_groot import write_tiny_groot

    return write_tiny_groot(tmp_path_factory.mktemp("groot"))


@pytest.fixture(scope="session")
def evo1_vlm(tmp_path_factory):
    """A random tiny InternVL3 folder (with weights) for the tiny EVO1, written once a session."""
    skip_unless_lerobot_has("evo1:Evo1FlowPolicy", "EVO1")
    from tests.lerobot_tiny_evo1 import write_tiny_internvl3

    return write_tiny_internvl3(tmp_path_factory.mktemp("evo1") / "internvl3")


@pytest.fixture(scope="session")
def eo1_vlm(tmp_path_factory):
    """A random tiny Qwen2.5-VL folder (with weights and processor) for the tiny EO-1, written once a session."""
    skip_unless_lerobot_has("eo1:EO1FlowPolicy", "EO-1")
    from tests.lerobot_tiny_eo1 import write_tiny_qwen2_5_vl

    return write_tiny_qwen2_5_vl(tmp_path_factory.mktemp("eo1") / "qwen2_5_vl")


@pytest.fixture(scope="session")
def vla_jepa_backbones(tmp_path_factory):
    """A random tiny Qwen3-VL and V-JEPA 2 (with weights) for the tiny VLA-JEPA, written once a session."""
    skip_unless_lerobot_has("vla_jepa:VLAJEPAFlowPolicy", "VLA-JEPA")
    from tests.lerobot_tiny_vla_jepa import write_tiny_backbones

    return write_tiny_backbones(tmp_path_factory.mktemp("vla_jepa"))


@pytest.fixture(scope="session")
def molmoact2_checkpoint(tmp_path_factory):
    """A random tiny MolmoAct2 checkpoint folder (with weights, tokenizer and processor config), written once a
    session."""
    skip_unless_lerobot_has("molmoact2:MolmoAct2FlowPolicy", "MolmoAct2")
    from tests.lerobot_tiny_molmoact2 import write_tiny_molmoact2

    return write_tiny_molmoact2(tmp_path_factory.mktemp("molmoact2") / "checkpoint")
