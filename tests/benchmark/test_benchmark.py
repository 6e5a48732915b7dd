"""Latency measurement: round-robin timing, the quantities it derives, and ``snapflow bench`` end to end."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import pytest
import torch

from snapflow.benchmark.architectures import architectures
from snapflow.benchmark.bench import run_bench
from snapflow.benchmark.latency import LatencyReport, LatencyRow, Timing, measure_latency, time_round_robin
from snapflow.cli import main
from snapflow.families import family_of
from snapflow.flow.modes import NAIVE_1, SNAPFLOW_1, SamplingMode
from snapflow.flow.solver import sample_actions
from snapflow.inference import compile_policy
from snapflow.inference.deploy import DEPLOY_ACTION_BOUND
from snapflow.nn import SnapFlowPolicy
from snapflow.policies.mlp import MLPFlowModel, MLPPolicyConfig
from tests.evaluation.figures import CYCLE, assert_figure
from tests.lerobot_tiny import randomise_target_time

OBSERVATION_DIM, CHUNK, ACTION_DIM = 5, 3, 2


@pytest.fixture
def student() -> SnapFlowPolicy:
    torch.manual_seed(0)
    model = MLPFlowModel(
        MLPPolicyConfig(
            observation_dim=OBSERVATION_DIM,
            action_dim=ACTION_DIM,
            chunk_length=CHUNK,
            hidden_dim=32,
            time_embedding_dim=16,
        )
    )
    return randomise_target_time(SnapFlowPolicy(model), std=0.3)


@pytest.fixture
def observation() -> torch.Tensor:
    return torch.randn(6, OBSERVATION_DIM, generator=torch.Generator().manual_seed(7))


def test_round_robin_warms_up_then_rotates_the_order_of_every_repeat():
    calls: list[str] = []
    functions = {name: (lambda name=name: calls.append(name)) for name in ("a", "b", "c")}
    timed = time_round_robin(functions, torch.device("cpu"), warmup=2, repeats=4)
    assert calls[:6] == ["a", "b", "c"] * 2  # warm-up, untimed
    assert calls[6:] == ["a", "b", "c", "b", "c", "a", "c", "a", "b", "a", "b", "c"]  # each repeat starts one later
    assert list(timed) == ["a", "b", "c"]
    assert all(
        isinstance(entry, Timing) and entry.repeats == 4 and 0 <= entry.median_ms <= entry.p90_ms
        for entry in timed.values()
    )
    with pytest.raises(ValueError, match="need repeats >= 1 and warmup >= 0"):
        time_round_robin(functions, torch.device("cpu"), warmup=0, repeats=0)


def test_timing_takes_the_median_and_the_90th_percentile():
    timing = Timing.of([5.0, 1.0, 4.0, 2.0, 3.0, 10.0, 6.0, 7.0, 8.0, 9.0])
    assert (timing.median_ms, timing.p90_ms, timing.repeats) == (5.5, 10.0, 10)


def test_latency_counts_passes_and_derives_shares_and_speedups(student, observation):
    passes = {"velocity": 0, "encode": 0}
    velocity, encode = student.velocity, student.encode

    def counted_velocity(*args):
        passes["velocity"] += 1
        return velocity(*args)

    def counted_encode(*args):
        passes["encode"] += 1
        return encode(*args)

    student.velocity, student.encode = counted_velocity, counted_encode
    noise = torch.randn(1, CHUNK, ACTION_DIM)
    modes = [SamplingMode(10, jump=False), SNAPFLOW_1]
    result = measure_latency(student, observation[:1], noise, modes, warmup=1, repeats=3)
    # per repeat: 10 + 1 denoising passes, and the same again end-to-end, each end-to-end run encoding once
    assert passes["velocity"] == 4 * (10 + 1) * 2
    assert passes["encode"] == 1 + 4 * (1 + 2)  # the shared context, then prefix timing and both end-to-end runs
    assert isinstance(result, LatencyReport) and list(result.modes) == ["teacher-10", "snapflow-1"]
    assert (result.warmup, result.repeats, result.device) == (1, 3, "cpu") and result.prefix.repeats == 3
    teacher, one_step = result.modes["teacher-10"], result.modes["snapflow-1"]
    assert isinstance(teacher, LatencyRow) and (teacher.nfe, one_step.nfe) == (10, 1)
    assert teacher.denoising_speedup == teacher.end_to_end_speedup == 1.0
    assert teacher.per_pass_ms == teacher.denoising.median_ms / 10
    assert one_step.denoising_speedup == teacher.denoising.median_ms / one_step.denoising.median_ms
    assert one_step.end_to_end_speedup == teacher.end_to_end.median_ms / one_step.end_to_end.median_ms
    assert one_step.denoising_share == one_step.denoising.median_ms / one_step.end_to_end.median_ms
    # the JSON form carries the derived quantities too
    row = result.to_dict()["modes"]["snapflow-1"]
    assert row["per_pass_ms"] == one_step.per_pass_ms and row["denoising_share"] == one_step.denoising_share
    assert row["denoising"] == {
        "median_ms": one_step.denoising.median_ms,
        "p90_ms": one_step.denoising.p90_ms,
        "repeats": 3,
    }


@pytest.mark.parametrize(
    "architecture, profile", [pytest.param("minivla", True, marks=pytest.mark.slow), ("mlp", False)]
)
def test_bench_cli_times_a_built_in_architecture_and_writes_every_result_file(architecture, profile, tmp_path, capsys):
    output = tmp_path / "bench"
    assert architecture in architectures()
    arguments = [
        "bench",
        "--architecture",
        architecture,
        "--warmup",
        "1",
        "--repeats",
        "3",
        "--output",
        str(output),
    ]
    assert main(arguments + ([] if profile else ["--no-profile"])) == 0
    report = json.loads((output / "bench.json").read_text())
    latency = report["latency"]
    assert list(latency["modes"]) == ["teacher-10", "teacher-5", "teacher-2", "snapflow-1"]
    assert [entry["nfe"] for entry in latency["modes"].values()] == [10, 5, 2, 1]
    assert latency["repeats"] == 3 and latency["warmup"] == 1 and latency["prefix"]["repeats"] == 3
    reference = latency["modes"]["teacher-10"]
    assert reference["denoising_speedup"] == reference["end_to_end_speedup"] == 1.0
    for entry in latency["modes"].values():
        assert (
            0 < entry["denoising"]["median_ms"] <= entry["denoising"]["p90_ms"] and entry["denoising"]["repeats"] == 3
        )
        assert entry["per_pass_ms"] == pytest.approx(entry["denoising"]["median_ms"] / entry["nfe"])
        assert entry["denoising_speedup"] == pytest.approx(
            reference["denoising"]["median_ms"] / entry["denoising"]["median_ms"]
        )
        assert entry["end_to_end_speedup"] == pytest.approx(
            reference["end_to_end"]["median_ms"] / entry["end_to_end"]["median_ms"]
        )
        # what a pass adds to a chunk: end-to-end minus the prefix, over NFE
        assert entry["marginal_per_pass_ms"] == pytest.approx(
            (entry["end_to_end"]["median_ms"] - latency["prefix"]["median_ms"]) / entry["nfe"]
        )
    assert report["jump_to_teacher_pass_ratio"] == pytest.approx(
        latency["modes"]["snapflow-1"]["per_pass_ms"] / reference["per_pass_ms"]
    )
    assert report["jump_to_teacher_marginal_ratio"] == pytest.approx(
        latency["modes"]["snapflow-1"]["marginal_per_pass_ms"] / reference["marginal_per_pass_ms"]
    )
    # throughput at the default batch sizes, of the 10-step teacher and the one-step mode
    assert list(report["throughput"]) == ["1", "8", "32"]
    for size, entry in report["throughput"].items():
        assert list(entry) == ["teacher-10", "snapflow-1"]
        for timed in entry.values():
            assert timed["chunks_per_s"] == pytest.approx(int(size) * 1e3 / timed["end_to_end"]["median_ms"])
    assert "| 32 |" in (output / "bench.md").read_text()
    assert (
        report["machine"]["torch"] == torch.__version__ and report["fast_path"] is None and "first_chunk" not in report
    )
    assert (
        report["subject"] == f"{architecture} (full size, random weights)"
        and report["details"]["policy_type"] == architecture
    )
    expected = family_of(architecture).random_policy(architecture, "cpu")
    assert report["details"]["parameters"] == sum(parameter.numel() for parameter in expected.policy.parameters())
    assert report["details"]["config"] == expected.processor.config.to_dict()
    assert report["dtype"] == {
        "requested": "float32",
        "inputs": "float32",
        "parameters": {"float32": report["details"]["parameters"]},
        "groups": {"(all)": {"float32": report["details"]["parameters"]}},
    }
    assert "weights " in (output / "bench.md").read_text()
    assert "profile_table" not in report
    if profile:
        summary = report["profile_one_step"]
        assert summary["calls"] == 20 and summary["wall_ms_per_call"] > 0 and 0 <= summary["outside_aten_share"] <= 1
        assert "aten::" in (output / "profile.txt").read_text()
    else:
        assert "profile_one_step" not in report and not (output / "profile.txt").exists()
    # the plot: per mode a prefix bar (C0, thin for a small prefix) under a denoising bar (C1)
    assert_figure(output / "latency.png", (6.5, 3.8), {CYCLE[0]: 0.0003, CYCLE[1]: 0.01})
    row = f"| snapflow-1 | 1 | {latency['modes']['snapflow-1']['denoising']['median_ms']:.2f} "
    assert row in (output / "bench.md").read_text() and row in capsys.readouterr().out


def test_bench_cli_refuses_an_unknown_architecture_and_a_missing_subject(tmp_path, capsys):
    with pytest.raises(SystemExit) as exit_:
        main(["bench", "--architecture", "gpt", "--output", str(tmp_path)])
    assert exit_.value.code == 2 and "invalid choice: 'gpt'" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exit_:
        main(["bench", "--output", str(tmp_path)])
    assert (
        exit_.value.code == 2 and "one of the arguments --policy --architecture is required" in capsys.readouterr().err
    )
    assert not (tmp_path / "bench.json").exists()


def test_bench_cli_names_a_policy_folder_that_does_not_exist(tmp_path, capsys):
    assert main(["bench", "--policy", str(tmp_path / "nowhere"), "--output", str(tmp_path)]) == 2
    assert "snapflow bench: error: " in (error := capsys.readouterr().err) and str(tmp_path / "nowhere") in error
    assert not (tmp_path / "bench.json").exists()


@pytest.mark.slow
def test_compiled_one_pass_expert_computes_what_the_eager_one_does(student, observation):
    noise = torch.randn(len(observation), CHUNK, ACTION_DIM, generator=torch.Generator().manual_seed(0))
    eager = sample_actions(student, observation, noise, SNAPFLOW_1)
    assert compile_policy(student, "default") is student
    assert torch.allclose(sample_actions(student, observation, noise, SNAPFLOW_1), eager, atol=1e-5)
    with pytest.raises(ValueError, match="unknown compile mode 'fastest'"):
        compile_policy(student, "fastest")


def test_a_teacher_checkpoint_is_timed_at_its_naive_one_step_not_under_snapflows_name(tmp_path):
    """A teacher (no phi_s) has no jump to time: its 1-NFE row is the naive step, named so; a student's is SnapFlow's."""
    student = family_of("mlp").random_policy("mlp", "cpu")
    teacher = replace(student, policy=SnapFlowPolicy(student.policy.model, target_time=False))
    assert student.bench_subject("student").one_step == SNAPFLOW_1
    subject = teacher.bench_subject("teacher")
    assert subject.one_step == NAIVE_1
    report = run_bench(subject, warmup=0, repeats=1, profile=False)
    assert list(report.latency.modes) == ["teacher-10", "teacher-5", "teacher-2", "naive-1"]


def test_a_policy_whose_own_sampler_takes_other_steps_is_timed_at_them_first():
    """Multi-task DiT integrates 100 steps by default: its own count is the reference row, the usual teacher modes
    beside it; a count among them is not timed twice."""
    subject = family_of("mlp").random_policy("mlp", "cpu").bench_subject("student")
    report = run_bench(replace(subject, own_steps=20), warmup=0, repeats=1, profile=False)
    assert list(report.latency.modes) == ["teacher-20", "teacher-10", "teacher-5", "teacher-2", "snapflow-1"]
    report = run_bench(replace(subject, own_steps=10), warmup=0, repeats=1, profile=False)
    assert list(report.latency.modes) == ["teacher-10", "teacher-5", "teacher-2", "snapflow-1"]


def test_parameter_dtypes_lists_the_groups_that_run_in_each_precision():
    from torch import nn

    from snapflow.benchmark.subjects import parameter_dtypes

    model = nn.Sequential(nn.Linear(2, 3), nn.Sequential(nn.Linear(3, 4), nn.Linear(4, 1)))
    assert parameter_dtypes(model) == {"(all)": {"float32": 9 + 16 + 5}}
    model[1][1].to(torch.bfloat16)  # a policy that keeps some layers in another precision
    assert parameter_dtypes(model) == {"0": {"float32": 9}, "1.0": {"float32": 16}, "1.1": {"bfloat16": 5}}
    wrapped = nn.Sequential(nn.Sequential(model))  # an adapter around its policy spends no level of the depth
    assert parameter_dtypes(wrapped, depth=2) == {
        "0.0.0": {"float32": 9},
        "0.0.1.0": {"float32": 16},
        "0.0.1.1": {"bfloat16": 5},
    }


def test_a_bfloat16_built_in_policy_is_timed_in_bfloat16(tmp_path):
    arguments = ["bench", "--architecture", "minivla", "--dtype", "bfloat16", "--warmup", "0", "--repeats", "1"]
    extra = ["--batch-sizes", "1", "--distill-batch-sizes", "2,3"]
    assert main([*arguments, "--no-profile", *extra, "--output", str(tmp_path)]) == 0
    report = json.loads((tmp_path / "bench.json").read_text())
    assert set(report["dtype"]["groups"]["(all)"]) == {"bfloat16"}
    # the dtype asked for, and what ran: here the same
    assert report["dtype"]["requested"] == "bfloat16" and set(report["dtype"]["parameters"]) == {"bfloat16"}
    assert "M bfloat16 (asked: bfloat16)" in (tmp_path / "bench.md").read_text()
    assert [row["batch_size"] for row in report["distill_step"]["rows"]] == [2, 3]
    assert all(row["step_ms_median"] > 0 and row["peak_memory_gib"] > 0 for row in report["distill_step"]["rows"])


@pytest.mark.slow
def test_the_gpu_latency_script_times_the_deploy_fast_path_from_a_cold_then_a_warm_compile_cache(tmp_path):
    """``scripts/gpu_latency.sh`` in its short form, as a user starts it: two bench processes on the MLP, the first
    compiling into an empty cache, the second reading it back."""
    finished = subprocess.run(
        ["bash", str(Path(__file__).resolve().parents[2] / "scripts" / "gpu_latency.sh"), str(tmp_path)],
        env={**os.environ, "SHORT": "1", "PATH": f"{Path(sys.executable).parent}{os.pathsep}{os.environ['PATH']}"},
        capture_output=True,
        text=True,
        stdin=subprocess.DEVNULL,
        timeout=900,
    )
    assert finished.returncode == 0, finished.stderr[-3000:]
    assert "mlp-cpu-cold: exit 0" in finished.stdout and "mlp-cpu: exit 0" in finished.stdout
    cold, warm = (json.loads((tmp_path / run / "bench.json").read_text()) for run in ("mlp-cpu-cold", "mlp-cpu"))
    assert cold["fast_path"] == warm["fast_path"] == "deploy"
    assert "cold start" in (tmp_path / "mlp-cpu-cold" / "bench.md").read_text()
    cold, warm = cold["first_chunk"], warm["first_chunk"]
    assert cold["start"] == "cold" and cold["cache_misses"] > 0
    # recorded by its name alone: a record holds no absolute path of this machine
    assert cold["compile_cache"] == warm["compile_cache"] == "compile-cache"
    assert warm["start"] == "warm" and warm["cache_misses"] == 0 and warm["cache_hits"] > 0
    for first in (cold, warm):
        # the prefix and the jump as one graph, its actions within the stated bound of the eager policy's
        assert first["graphs"] == 1 and first["seconds"] > 0
        assert first["action_bound"] == DEPLOY_ACTION_BOUND and first["within_bound"]
        assert first["max_abs_action_difference"] <= DEPLOY_ACTION_BOUND


@pytest.mark.slow
def test_the_deploy_parity_script_adds_the_fast_paths_parts_one_at_a_time_against_eager(tmp_path):
    """``scripts/deploy_parity.py`` as a user starts it, on the MLP on a CPU: the parts that apply there (compiled,
    then fused), each measured against eager and against the part before it."""
    finished = subprocess.run(
        [sys.executable, str(Path(__file__).resolve().parents[2] / "scripts" / "deploy_parity.py")]
        + ["--architecture", "mlp", "--device", "cpu", "--output", str(tmp_path)],
        capture_output=True,
        text=True,
        stdin=subprocess.DEVNULL,
        timeout=600,
    )
    assert finished.returncode == 0, finished.stderr[-3000:]
    parity = json.loads((tmp_path / "parity.json").read_text())
    assert [stage["stage"] for stage in parity["stages"]] == [
        "+ prefix and velocity compiled (reduce-overhead)",
        "+ one-step chunk as one graph (deploy)",
    ], "no vision tower and no TF32 on an MLP on a CPU"
    # float32 compiled on a CPU: rounding only, as the fast paths promise (within 1e-4 of eager)
    assert all(0 <= stage["max_abs_to_eager"] <= 1e-4 for stage in parity["stages"])
    assert parity["bound"] == DEPLOY_ACTION_BOUND and parity["eager_abs_max"] > 0


def test_a_prompt_length_is_refused_for_a_policy_that_reads_no_tokenized_prompt(tmp_path, capsys):
    arguments = ["bench", "--architecture", "mlp", "--prompt-tokens", "3", "--repeats", "1", "--warmup", "0"]
    assert main([*arguments, "--no-progress", "--output", str(tmp_path)]) == 2
    assert "reads no tokenized prompt (a LeRobot policy does)" in capsys.readouterr().err
