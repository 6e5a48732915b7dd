"""Latency measurement: round-robin timing, the quantities it derives, and ``snapflow bench`` end to end."""

from __future__ import annotations

import json

import pytest
import torch

from snapflow.benchmark.latency import measure_latency, time_round_robin
from snapflow.cli import main
from snapflow.flow.solver import SNAPFLOW_1, SamplingMode


def test_round_robin_warms_up_then_rotates_the_order_of_every_repeat():
    calls: list[str] = []
    functions = {name: (lambda name=name: calls.append(name)) for name in ("a", "b", "c")}
    timed = time_round_robin(functions, torch.device("cpu"), warmup=2, repeats=4)
    assert calls[:6] == ["a", "b", "c"] * 2  # warm-up, untimed
    assert calls[6:] == ["a", "b", "c", "b", "c", "a", "c", "a", "b", "a", "b", "c"]  # each repeat starts one later
    assert all(entry["repeats"] == 4 and 0 <= entry["median_ms"] <= entry["p90_ms"] for entry in timed.values())


def test_latency_counts_passes_and_derives_shares_and_speedups(student, batch):
    observation, _ = batch
    passes = {"velocity": 0, "encode": 0}
    velocity, encode = student.velocity, student.encode

    def counted_velocity(*args):
        passes["velocity"] += 1
        return velocity(*args)

    def counted_encode(*args):
        passes["encode"] += 1
        return encode(*args)

    student.velocity, student.encode = counted_velocity, counted_encode
    noise = torch.randn(1, *batch[1].shape[1:])
    modes = [SamplingMode(10, jump=False), SNAPFLOW_1]
    result = measure_latency(student, observation[:1], noise, modes, warmup=1, repeats=3)
    # per repeat: 10 + 1 denoising passes, and the same again end-to-end, each end-to-end run encoding once
    assert passes["velocity"] == 4 * (10 + 1) * 2
    assert passes["encode"] == 1 + 4 * (1 + 2)  # the shared context, then prefix timing and both end-to-end runs
    teacher, one_step = result["modes"]["teacher-10"], result["modes"]["snapflow-1"]
    assert teacher["denoising_speedup"] == teacher["end_to_end_speedup"] == 1.0
    assert teacher["per_pass_ms"] == teacher["denoising"]["median_ms"] / 10
    assert one_step["denoising_speedup"] == teacher["denoising"]["median_ms"] / one_step["denoising"]["median_ms"]
    assert one_step["denoising_share"] == one_step["denoising"]["median_ms"] / one_step["end_to_end"]["median_ms"]


def test_bench_cli_times_the_built_in_architecture_and_writes_every_result_file(tmp_path, capsys):
    output = tmp_path / "bench"
    assert main(["bench", "--architecture", "minivla", "--warmup", "1", "--repeats", "3", "--output-dir", str(output)]) == 0
    report = json.loads((output / "bench.json").read_text())
    assert list(report["latency"]["modes"]) == ["teacher-10", "teacher-5", "teacher-2", "snapflow-1"]
    assert report["latency"]["repeats"] == 3 and report["machine"]["torch"] == torch.__version__
    assert report["details"]["parameters"] > 0 and report["profile_one_step"]["calls"] == 20
    assert (output / "latency.png").stat().st_size > 0 and "aten::" in (output / "profile.txt").read_text()
    assert "| snapflow-1 | 1 |" in (output / "bench.md").read_text() and "| snapflow-1 | 1 |" in capsys.readouterr().out

    assert main(["bench", "--architecture", "gpt", "--output-dir", str(output)]) == 2
    assert "unknown architecture 'gpt'" in capsys.readouterr().err


def test_compiled_one_pass_expert_computes_what_the_eager_one_does(student, batch):
    from snapflow.benchmark.bench import compile_velocity
    from snapflow.flow.solver import sample_actions

    observation, actions = batch
    noise = torch.randn_like(actions)
    eager = sample_actions(student, observation, noise, SNAPFLOW_1)
    compile_velocity(student, "default")
    assert torch.allclose(sample_actions(student, observation, noise, SNAPFLOW_1), eager, atol=1e-5)
    with pytest.raises(ValueError, match="unknown compile mode 'fastest'"):
        compile_velocity(student, "fastest")
