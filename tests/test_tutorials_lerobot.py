"""The LeRobot tutorials (``docs/tutorials/``: distil and lerobot-eval, serve, deploy, ONNX) typed into one shell in a
clone of the repository, in order, each starting from the first one's student. A module of its own, so that CI's
workers run it beside the other tutorials rather than after them."""

from __future__ import annotations

import pytest

from tests.test_tutorials import LEROBOT_SESSION, NEEDS_PLUGINS, run_in_a_clone


@pytest.mark.slow
@pytest.mark.lerobot
@NEEDS_PLUGINS
def test_the_lerobot_tutorials_run_top_to_bottom(tmp_path):
    output = run_in_a_clone(LEROBOT_SESSION, tmp_path)
    assert "the executed actions kept: True" in output
    assert "| snapflow-1 |" in output  # the served episode's summary and the latency table
    clone = tmp_path / "snapflow" / "outputs" / "tutorial"
    for mode in ("snapflow-1", "teacher-10"):
        assert (clone / f"eval-{mode}" / "eval_info.json").is_file(), "lerobot-eval ran in both modes"
    assert (clone / "onnx" / "model.onnx").is_file() and (clone / "eval-onnx" / "report.json").is_file()
