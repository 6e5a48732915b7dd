"""What a distillation step costs per SnapFlow target: ``time_training_steps`` and ``snapflow bench-targets``."""

from __future__ import annotations

import json

import pytest
import torch

from snapflow.benchmark.training_cost import time_training_steps
from snapflow.cli import main
from snapflow.flow.time_sampling import UniformTimeSampler
from snapflow.nn import SnapFlowPolicy
from snapflow.policies.mlp import MLPFlowModel, MLPPolicyConfig
from snapflow.training.recipes import TargetOption
from snapflow.training.stages import train_teacher
from tests.training.fixtures import TINY, synthetic_demonstrations, train_config


def test_every_option_trains_its_own_copy_of_the_student_on_the_same_batch():
    torch.manual_seed(0)
    student = SnapFlowPolicy(
        MLPFlowModel(
            MLPPolicyConfig(observation_dim=5, action_dim=2, chunk_length=3, hidden_dim=16, time_embedding_dim=8)
        )
    )
    before = {name: value.clone() for name, value in student.state_dict().items()}
    observation, actions = torch.randn(8, 5), torch.randn(8, 3, 2)
    options = [TargetOption.parse(text) for text in ("euler:2", "euler:2,4", "bootstrap:4")]
    result = time_training_steps(student, observation, actions, options, UniformTimeSampler(), warmup=1, repeats=3)
    assert [row["option"] for row in result["rows"]] == ["euler-2", "euler-2-4", "bootstrap-4"]
    assert [row["label"] for row in result["rows"]] == ["K = 2", "K = 2 -> 4", "bootstrapped (K -> 4)"]
    assert [row["teacher_passes_per_row"] for row in result["rows"]] == [2.0, 3.0, 2.0]
    assert (result["batch_size"], result["warmup"], result["repeats"]) == (8, 1, 3)
    assert result["rows"][0]["relative_to_first"] == 1.0
    assert all(0 < row["step_ms_median"] <= row["step_ms_p90"] for row in result["rows"])
    assert all(torch.equal(before[name], value) for name, value in student.state_dict().items()), (
        "the student itself never trains"
    )
    with pytest.raises(ValueError, match="time at least one target option"):
        time_training_steps(student, observation, actions, [], UniformTimeSampler())
    with pytest.raises(ValueError, match="need warmup >= 0 and repeats >= 1"):
        time_training_steps(student, observation, actions, options, UniformTimeSampler(), repeats=0)


def test_bench_targets_times_every_target_on_the_same_batch_and_writes_its_files(tmp_path, capsys):
    data = synthetic_demonstrations().save(tmp_path / "demos")
    teacher = tmp_path / "teacher"
    train_teacher(data, teacher, TINY, train_config(3), progress=False)
    output = tmp_path / "cost"
    assert (
        main(
            [
                "bench-targets",
                "--teacher",
                str(teacher),
                "--data",
                str(data),
                "--targets",
                "euler:2",
                "euler:2,8",
                "bootstrap:4",
                "--batch-size",
                "8",
                "--warmup",
                "1",
                "--repeats",
                "4",
                "--output",
                str(output),
                "--no-progress",
            ]
        )
        == 0
    )
    result = json.loads((output / "training_cost.json").read_text())
    assert [row["option"] for row in result["rows"]] == ["euler-2", "euler-2-8", "bootstrap-4"]
    assert [row["teacher_passes_per_row"] for row in result["rows"]] == [2.0, 5.0, 2.0]
    assert result["rows"][0]["relative_to_first"] == 1.0 and result["repeats"] == 4 and result["batch_size"] == 8
    assert (
        result["teacher"] == str(teacher)
        and result["data"] == str(data)
        and result["machine"]["torch"] == torch.__version__
    )
    assert all(0 < row["step_ms_median"] <= row["step_ms_p90"] for row in result["rows"])
    for row in result["rows"][1:]:
        assert row["relative_to_first"] == pytest.approx(row["step_ms_median"] / result["rows"][0]["step_ms_median"])
    assert (
        "| bootstrapped (K -> 4) | 2 + 1 |" in (output / "training_cost.md").read_text()
        and "K = 2 -> 8" in capsys.readouterr().out
    )
    with pytest.raises(SystemExit) as refusal:  # argparse's own refusal, before anything is timed
        main(["bench-targets", "--teacher", str(teacher), "--data", str(data), "--targets", "euler:two"])
    assert refusal.value.code == 2 and "target steps must be integers" in capsys.readouterr().err
