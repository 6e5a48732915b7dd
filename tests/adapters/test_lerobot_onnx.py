"""``snapflow export`` of a distilled LeRobot SmolVLA (and X-VLA, multi-task DiT; GR00T is refused by name): one ONNX
graph over LeRobot's pre-processed batch (prefix and jump), saved beside the policy's config and processors, loaded
back by ``snapflow eval`` with those processors, giving the PyTorch student's actions."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

pytest.importorskip("lerobot", reason="LeRobot is installed by the README's test command; this environment lacks it")
pytest.importorskip(
    "onnxruntime", reason='the ONNX export needs pip install "snapflow-vla[onnx]" (the test extra has it)'
)

from snapflow.adapters.lerobot.evaluation import load_lerobot_policy  # noqa: E402
from snapflow.cli import main  # noqa: E402
from snapflow.flow.modes import SNAPFLOW_1, TEACHER_10  # noqa: E402
from snapflow.flow.solver import sample_actions  # noqa: E402
from snapflow.policies.checkpoint import CheckpointError  # noqa: E402
from tests.lerobot_tiny import PI_SKIP, save_tiny_student  # noqa: E402
from tests.lerobot_tiny_multi_task_dit import save_tiny_multi_task_dit_student  # noqa: E402
from tests.lerobot_tiny_xvla import save_tiny_xvla_student  # noqa: E402

STATE_DIM, IMAGE_SIZE = 6, 64


def _raw_batch(rows: int, seed: int) -> tuple[np.ndarray, list[str], np.ndarray]:
    generator = np.random.default_rng(seed)
    states = generator.standard_normal((rows, 39)).astype(np.float32)  # a benchmark's full state; the policy reads 6
    images = generator.integers(0, 256, (rows, IMAGE_SIZE, IMAGE_SIZE, 3), dtype=np.uint8)
    return states, ["push the red cube", "open the drawer", "pick the blue cube"][:rows], images


@pytest.mark.slow
def test_a_distilled_smolvla_exports_to_one_graph_that_gives_its_actions(vlm_directory, tmp_path, capsys):
    import onnx

    from snapflow.adapters.lerobot.local_vlm import bundle_vlm

    student = save_tiny_student(vlm_directory, tmp_path / "student", STATE_DIM, "observation.images.top", IMAGE_SIZE)
    bundle_vlm(student)  # as a student is kept: its SmolVLM inside, its tokenizer carried by its tokenizer step
    (student / "snapflow.json").unlink()  # as lerobot-train leaves its checkpoint: the student config's label alone
    output = tmp_path / "onnx"
    assert main(["export", "--policy", str(student), "--output", str(output)]) == 0
    assert "largest difference to PyTorch" in capsys.readouterr().out
    marker = json.loads((output / "snapflow.json").read_text())
    assert marker["policy"] == "smolvla" and marker["onnx"]["source"] == str(student)
    assert not (output / "model.safetensors").exists(), "the weights live in the graph"
    assert (output / "policy_preprocessor.json").is_file() and (output / "config.json").is_file()
    graph = onnx.load(output / "model.onnx").graph
    assert not {"Loop", "Scan", "If"} & {node.op_type for node in graph.node}, "no sampling loop may be left"

    eager, exported = load_lerobot_policy(student), load_lerobot_policy(output)
    assert exported.exported and exported.distilled
    for rows in (1, 3):  # a graph pinned to batch 1 runs a batch row by row
        raw = _raw_batch(rows, rows)
        noise = torch.randn(rows, 4, 4, generator=torch.Generator().manual_seed(rows))
        expected = sample_actions(eager.policy, eager.processor.observation(*raw), noise, SNAPFLOW_1)
        # each through its own processors: the export's pads every prompt to the length it was traced at
        batch = exported.processor.observation(*raw)
        assert batch["observation.language.tokens"].shape[1] == 16
        actions = sample_actions(exported.policy, batch, noise, SNAPFLOW_1)
        torch.testing.assert_close(actions, expected, atol=1e-4, rtol=1e-4)
    with pytest.raises(
        CheckpointError,
        match="onnx export of a one-step student: it runs snapflow-1 only; for teacher-10, use the policy it was exported from",
    ):
        exported.check_mode(TEACHER_10)

    # snapflow eval runs it closed loop beside the PyTorch student, LeRobot's processors around both
    arguments = ["eval", "--policy", f"{student}=snapflow-1", f"{output}=snapflow-1", "--tasks", "reach-v3"]
    assert main([*arguments, "--episodes", "1", "--output", str(tmp_path / "eval"), "--no-progress"]) == 0
    report = json.loads((tmp_path / "eval" / "report.json").read_text())
    assert [row["mode"] for row in report["rows"].values()] == ["snapflow-1", "snapflow-1"]
    assert all(row["success"]["reach-v3"]["episodes"] == 1 for row in report["rows"].values())


@pytest.mark.slow
@PI_SKIP
@pytest.mark.parametrize("policy_type", ["xvla", "multi_task_dit"])
def test_a_student_beyond_the_pi0_family_exports_to_one_graph_that_gives_its_actions(
    policy_type, vlm_directory, request, tmp_path
):
    """X-VLA (its Florence-2 prefix counting its views without a host synchronisation) and multi-task DiT (CLIP's
    encoders, its flow run the other way): prefix and jump in one graph, the PyTorch student's actions through the
    same processors."""
    if policy_type == "xvla":
        student = save_tiny_xvla_student(vlm_directory, tmp_path / "student")
    else:
        student = save_tiny_multi_task_dit_student(request.getfixturevalue("clip_directory"), tmp_path / "student")
    output = tmp_path / "onnx"
    assert main(["export", "--policy", str(student), "--output", str(output)]) == 0
    assert json.loads((output / "snapflow.json").read_text())["policy"] == policy_type
    eager, exported = load_lerobot_policy(student), load_lerobot_policy(output)
    for rows in (1, 3):
        raw = _raw_batch(rows, rows)
        noise = torch.randn(rows, 4, 4, generator=torch.Generator().manual_seed(rows))
        expected = sample_actions(eager.policy, eager.processor.observation(*raw), noise, SNAPFLOW_1)
        actions = sample_actions(exported.policy, exported.processor.observation(*raw), noise, SNAPFLOW_1)
        torch.testing.assert_close(actions, expected, atol=1e-4, rtol=1e-4)


def test_a_groot_student_is_refused_export_by_name(groot_checkpoint, tmp_path, capsys):
    """GR00T N1.7's Qwen3-VL prefix computes its rotary positions on the host: no one graph, so no export, said so."""
    from tests.lerobot_tiny_groot import save_tiny_groot_student

    student = save_tiny_groot_student(groot_checkpoint, tmp_path / "student")
    assert main(["export", "--policy", str(student), "--output", str(tmp_path / "onnx")]) == 2
    assert "snapflow does not export a groot student: Qwen3-VL's multimodal rotary positions" in capsys.readouterr().err
    assert not (tmp_path / "onnx").exists()
