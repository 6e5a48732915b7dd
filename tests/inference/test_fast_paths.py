"""Where to add a fast path: one ``register_fast_path`` call, and ``snapflow bench``, ``snapflow eval`` and a LeRobot
adapter's sampling run it. The throw-away fast path here counts the velocity's calls; nothing else in the package is
touched. Then the registry's refusals and the deprecated ``--compile`` flag."""

from __future__ import annotations

import argparse
import json
import re
from collections import Counter
from pathlib import Path
from typing import Any

import pytest
import torch

import snapflow.inference.compile as compile_module
from snapflow.cli import build_parser, main
from snapflow.cli.common import COMPILE_FAST_PATHS
from snapflow.envs.factory import BENCHMARKS
from snapflow.flow.modes import SNAPFLOW_1, SamplingMode
from snapflow.inference.compile import COMPILE_MODES
from snapflow.inference.fast_paths import FAST_PATHS, FastPath, apply_fast_path, register_fast_path
from snapflow.nn import SnapFlowPolicy
from snapflow.policies.checkpoint import policy_metadata, write_policy
from snapflow.policies.factory import default_config, make_model, make_processor, policy_type
from snapflow.policies.normalization import NormalizationStats
from tests.test_where_to_add import GOALS, Line

#: the velocity calls the throw-away fast path counted, over every policy it was applied to
COUNTED: Counter[str] = Counter()


def count_velocity_calls(policy: Any) -> Any:
    """The throw-away fast path: the policy's velocity replaced on the instance by one that counts its calls."""
    velocity = policy.velocity

    def counted(*args: Any, **kwargs: Any) -> Any:
        COUNTED["velocity"] += 1
        return velocity(*args, **kwargs)

    policy.velocity = counted
    return policy


@pytest.fixture
def counting():
    register_fast_path("counting", f"{__name__}:count_velocity_calls", "count the velocity's calls")
    COUNTED.clear()
    yield COUNTED
    del FAST_PATHS["counting"]


def test_a_registered_fast_path_is_what_snapflow_bench_times(tmp_path, counting, capsys):
    output = tmp_path / "bench"
    arguments = ["bench", "--architecture", "mlp", "--fast-path", "counting", "--warmup", "1", "--repeats", "2"]
    assert main([*arguments, "--no-profile", "--batch-sizes", "1", "--output", str(output)]) == 0
    report = json.loads((output / "bench.json").read_text())
    assert report["fast_path"] == "counting"
    assert (
        "fast path: counting;" in (output / "bench.md").read_text()
        and "fast path: counting;" in capsys.readouterr().out
    )
    # every timed call of every mode (teacher 10, 5, 2 steps and the jump) ran through it, warm-up included
    assert counting["velocity"] >= (1 + 2) * (10 + 5 + 2 + 1)


def _line_policy(folder: Path) -> Path:
    """A random MLP teacher on the throw-away line environment of tests/test_where_to_add.py (20-step episodes, no
    simulator): what eval runs cheaply."""
    instructions = [Line().instruction(task) for task in GOALS]
    config = default_config("mlp", Line.state_dim, Line.action_dim, instructions)
    entries = policy_type("mlp").processor_class.state_entries(config, instructions)
    stats = NormalizationStats([0.0] * entries, [1.0] * entries, [0.0] * Line.action_dim, [1.0] * Line.action_dim)
    policy = SnapFlowPolicy(make_model(config))
    folder.mkdir()
    write_policy(folder, policy, policy_metadata(policy, make_processor(config, stats, instructions)))
    return folder


def test_a_registered_fast_path_is_what_snapflow_eval_runs(tmp_path, counting, monkeypatch):
    monkeypatch.setitem(BENCHMARKS, "line", Line)
    policy = _line_policy(tmp_path / "policy")
    arguments = ["eval", "--policy", str(policy), "--modes", "teacher-2", "--env", "line", "--episodes", "1"]
    assert main([*arguments, "--fast-path", "counting", "--output", str(tmp_path / "eval"), "--no-progress"]) == 0
    assert counting["velocity"] > 0 and counting["velocity"] % 2 == 0, "two passes a chunk, all through the fast path"


@pytest.mark.lerobot
def test_a_registered_fast_path_is_what_a_lerobot_adapters_sampling_runs(tmp_path, counting):
    pytest.importorskip(
        "lerobot", reason="LeRobot is installed by the README's test command; this environment lacks it"
    )
    from snapflow.adapters.lerobot import wrap_policy
    from tests.lerobot_tiny import build_tiny_smolvla, tiny_batch, write_tiny_smolvlm

    adapter = wrap_policy(build_tiny_smolvla(write_tiny_smolvlm(tmp_path / "vlm")))
    assert apply_fast_path(adapter, "counting") is adapter
    observation = tiny_batch(batch_size=1)
    for mode, calls in ((SNAPFLOW_1, 1), (SamplingMode(3, jump=False), 1 + 3)):
        adapter.use_sampling_mode(mode)
        with torch.no_grad():
            adapter.policy.predict_action_chunk(observation)  # LeRobot's own sampling
        assert counting["velocity"] == calls


@pytest.mark.slow
@pytest.mark.lerobot
def test_a_registered_fast_path_is_what_eval_in_lerobots_environment_runs(tmp_path, counting):
    pytest.importorskip(
        "lerobot", reason="LeRobot is installed by the README's test command; this environment lacks it"
    )
    from tests.lerobot_tiny import save_tiny_student, write_tiny_smolvlm

    student = save_tiny_student(write_tiny_smolvlm(tmp_path / "vlm"), tmp_path / "student")
    arguments = ["eval", "--lerobot-env", "metaworld", "--env-task", "reach-v3", "--policy", str(student)]
    arguments += ["--episodes", "1", "--modes", "snapflow-1", "--max-episode-steps", "4", "--fast-path", "counting"]
    assert main([*arguments, "--output", str(tmp_path / "eval"), "--no-progress"]) == 0
    assert json.loads((tmp_path / "eval" / "report.json").read_text())["fast_path"] == "counting"
    assert counting["velocity"] > 0


def test_an_unregistered_fast_path_is_refused_with_the_known_ones(tmp_path, capsys):
    with pytest.raises(
        ValueError, match="unknown fast path 'counting'; choose one of deploy, compile, compile-reduce-overhead"
    ):
        apply_fast_path(torch.nn.Linear(1, 1), "counting")
    with pytest.raises(SystemExit):
        main(["bench", "--architecture", "mlp", "--fast-path", "counting", "--output", str(tmp_path / "out")])
    assert "invalid choice: 'counting' (choose from 'deploy', 'compile', " in capsys.readouterr().err


def test_a_second_fast_path_of_a_name_is_refused_and_the_first_kept():
    before = FAST_PATHS["compile"]
    with pytest.raises(ValueError, match="a fast path named 'compile' is registered already"):
        register_fast_path("compile", f"{__name__}:count_velocity_calls", "count the velocity's calls")
    assert FAST_PATHS["compile"] is before


def test_a_fast_path_that_returns_another_policy_is_refused(monkeypatch):
    monkeypatch.setitem(FAST_PATHS, "copying", FastPath("copying", "copy:deepcopy", "a copy"))
    with pytest.raises(TypeError, match="fast path 'copying' returned another object"):
        apply_fast_path(torch.nn.Linear(1, 1), "copying")


def test_the_compile_fast_paths_compile_in_their_mode(monkeypatch):
    compiled: list[str] = []
    monkeypatch.setattr(compile_module, "compile_policy", lambda policy, mode: compiled.append(mode) or policy)
    policy = torch.nn.Linear(1, 1)
    for mode in COMPILE_MODES:
        assert apply_fast_path(policy, COMPILE_FAST_PATHS[mode]) is policy
    assert compiled == list(COMPILE_MODES)


@pytest.mark.parametrize("command", ["bench", "eval"])
def test_the_old_compile_flag_names_its_fast_path_with_one_warning(command, capsys):
    parser = build_parser()
    given = ["bench", "--architecture", "mlp"] if command == "bench" else ["eval", "--policy", "run"]
    assert parser.parse_args([*given, "--fast-path", "compile"]).fast_path == "compile"
    assert parser.parse_args(given).fast_path is None and capsys.readouterr().err == ""
    for mode, name in COMPILE_FAST_PATHS.items():
        assert parser.parse_args([*given, "--compile", mode]).fast_path == name
        warning = f"snapflow {command}: warning: --compile is deprecated; use --fast-path {name}\n"
        assert capsys.readouterr().err == warning
    with pytest.raises(SystemExit):
        parser.parse_args([*given, "--compile", "default", "--fast-path", "compile"])
    assert "argument --fast-path: not allowed with argument --compile" in capsys.readouterr().err
    commands = next(action for action in parser._actions if isinstance(action, argparse._SubParsersAction))
    command_help = commands.choices[command].format_help()
    # hidden: --compile itself never shows (bench's --compile-cache is another flag)
    assert "--fast-path" in command_help and re.search(r"--compile(?![-\w])", command_help) is None
