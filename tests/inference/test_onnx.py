"""``snapflow export --format onnx``: a one-step student as one ONNX graph (prefix and jump, no loop) that onnxruntime
runs to PyTorch's actions, loaded back as a policy that snapflow's evaluator and benchmark run, and refusals named."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from snapflow.benchmark.bench import run_bench
from snapflow.cli import main
from snapflow.flow.modes import SNAPFLOW_1, TEACHER_10
from snapflow.flow.solver import sample_actions
from snapflow.nn import SnapFlowPolicy
from snapflow.policies.checkpoint import CheckpointError, LoadedPolicy, load_policy, policy_metadata, write_policy
from snapflow.policies.factory import default_config, make_model, make_processor, policy_type
from snapflow.policies.normalization import NormalizationStats
from tests.lerobot_tiny import randomise_target_time

pytest.importorskip(
    "onnxruntime", reason='the ONNX export needs pip install "snapflow-vla[onnx]" (the test extra has it)'
)

STATE_DIM, ACTION_DIM = 39, 4
INSTRUCTIONS = ["push the puck to the goal", "open the drawer", "reach the goal"]


def _write_student(folder: Path, name: str, distilled: bool = True, **overrides) -> Path:
    """A random built-in policy on Meta-World's dimensions (phi_s non-zero) saved as a student (or as a teacher)."""
    torch.manual_seed(0)
    config = default_config(name, STATE_DIM, ACTION_DIM, INSTRUCTIONS, **overrides)
    state_dim = policy_type(name).processor_class.state_entries(config, INSTRUCTIONS)
    stats = NormalizationStats([0.1] * state_dim, [2.0] * state_dim, [0.0] * ACTION_DIM, [0.5] * ACTION_DIM)
    processor = make_processor(config, stats, INSTRUCTIONS)
    policy = SnapFlowPolicy(make_model(config), target_time=distilled)
    if distilled:
        randomise_target_time(policy, std=0.3)
    folder.mkdir(parents=True)
    write_policy(folder, policy, policy_metadata(policy, processor, **({"distill": {}} if distilled else {})))
    return folder


def _batch(loaded: LoadedPolicy, rows: int, seed: int = 0) -> tuple[dict, torch.Tensor]:
    """Varied observations (random states, every instruction, random images where read) and noise."""
    generator = np.random.default_rng(seed)
    processor = loaded.processor
    size = processor.image_size
    observation = processor.observation(
        generator.standard_normal((rows, STATE_DIM)).astype(np.float32),
        [INSTRUCTIONS[row % len(INSTRUCTIONS)] for row in range(rows)],
        generator.integers(0, 256, (rows, size, size, 3), dtype=np.uint8) if size else None,
    )
    noise = torch.randn(
        rows, processor.chunk_length, processor.action_dim, generator=torch.Generator().manual_seed(seed)
    )
    return observation, noise


@pytest.mark.parametrize(
    "name, overrides",
    [("minivla", {}), ("minivla", {"use_image": True, "image_size": 32}), ("mlp", {})],
    ids=["minivla-state", "minivla-image", "mlp"],
)
def test_the_onnx_student_gives_the_pytorch_students_actions_in_one_graph(name, overrides, tmp_path, capsys):
    import onnx

    student = _write_student(tmp_path / "student", name, **overrides)
    assert main(["export", "--policy", str(student), "--format", "onnx", "--output", str(tmp_path / "onnx")]) == 0
    assert "largest difference to PyTorch" in capsys.readouterr().out
    graph = onnx.load(tmp_path / "onnx" / "model.onnx").graph
    assert not {"Loop", "Scan", "If"} & {node.op_type for node in graph.node}, "no sampling loop may be left"
    assert [entry.name for entry in graph.output] == ["actions"]

    eager, exported = load_policy(student), load_policy(tmp_path / "onnx")
    assert exported.exported and not eager.exported
    record = exported.metadata["onnx"]
    assert record["source"] == str(student) and record["batch"] == "free" and record["opset"] == 18
    assert record["inputs"][0] == "noise" and record["max_abs_difference_to_pytorch"] <= 1e-4
    for rows in (1, 5):  # the batch dimension is free
        observation, noise = _batch(eager, rows, seed=rows)
        expected = sample_actions(eager.policy, observation, noise, SNAPFLOW_1)
        actions = sample_actions(exported.policy, observation, noise, SNAPFLOW_1)
        assert actions.shape == expected.shape
        torch.testing.assert_close(actions, expected, atol=1e-5, rtol=1e-5)
    # the benchmark times it at its one mode
    report = run_bench(exported.bench_subject("onnx"), warmup=0, repeats=2, profile=False)
    assert list(report.latency.modes) == ["snapflow-1"] and report.details["onnx"]["opset"] == 18


def test_an_onnx_student_answers_only_its_jump_and_a_teacher_or_a_bad_file_is_refused(tmp_path, capsys):
    student = _write_student(tmp_path / "student", "mlp")
    assert main(["export", "--policy", str(student), "--output", str(tmp_path / "onnx")]) == 0
    exported = load_policy(tmp_path / "onnx")
    with pytest.raises(
        CheckpointError,
        match="onnx export of a one-step student: it runs snapflow-1 only; for teacher-10, use the policy it was exported from",
    ):
        exported.check_mode(TEACHER_10)
    observation, noise = _batch(exported, 2)
    with pytest.raises(ValueError, match="answers only the jump from t = 1 to s = 0"):
        sample_actions(exported.policy, observation, noise, TEACHER_10)
    with pytest.raises(CheckpointError, match="it runs, it does not train"):
        load_policy(tmp_path / "onnx", target_time=True)

    teacher = _write_student(tmp_path / "teacher", "mlp", distilled=False)
    assert main(["export", "--policy", str(teacher), "--output", str(tmp_path / "teacher_onnx")]) == 2
    assert "is a flow-matching teacher: its one step is the naive one" in capsys.readouterr().err
    assert not (tmp_path / "teacher_onnx" / "model.onnx").exists()
    assert main(["export", "--policy", str(tmp_path / "onnx"), "--output", str(tmp_path / "again")]) == 2
    assert "is already an export (onnx)" in capsys.readouterr().err

    (tmp_path / "onnx" / "model.onnx").write_bytes(b"\x08\x07 not a graph")
    with pytest.raises(CheckpointError, match="model.onnx is corrupt or not an onnx graph"):
        load_policy(tmp_path / "onnx")


@pytest.mark.slow
def test_snapflow_eval_runs_the_onnx_student_closed_loop_beside_the_pytorch_one(tmp_path):
    import json

    student = _write_student(tmp_path / "student", "minivla")
    assert main(["export", "--policy", str(student), "--output", str(tmp_path / "onnx")]) == 0
    arguments = ["eval", "--policy", f"{student}=snapflow-1", f"{tmp_path / 'onnx'}=snapflow-1"]
    assert (
        main(
            [*arguments, "--tasks", "reach-v3", "--episodes", "2", "--output", str(tmp_path / "eval"), "--no-progress"]
        )
        == 0
    )
    report = json.loads((tmp_path / "eval" / "report.json").read_text())
    rows = report["rows"]
    assert len(rows) == 2 and all(row["mode"] == "snapflow-1" for row in rows.values())
    assert all(row["success"]["reach-v3"]["episodes"] == 2 for row in rows.values())
    assert len(report["latency"]) == 2
