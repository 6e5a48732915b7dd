"""Where to add an export format: one ``register_export_format`` call, and ``snapflow export --format``, the policy
source and the refusals serve it. The throw-away format here pickles the student's one-step module; nothing else in
the package is touched."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
import torch
from torch import Tensor, nn

from snapflow.cli import main
from snapflow.flow.modes import SNAPFLOW_1, TEACHER_10
from snapflow.flow.solver import sample_actions
from snapflow.inference.formats import EXPORT_FORMATS, register_export_format
from snapflow.inference.onnx import SINGLE, OneStepGraph
from snapflow.policies.checkpoint import CheckpointError
from snapflow.sources import open_policy
from tests.inference.test_onnx import _batch, _write_student


def export_pickled(policy: nn.Module, observation: Any, noise: Tensor, path: Path) -> dict[str, Any]:
    """The format's exporter: the one-step module, pickled whole, and checked against the policy once read back."""
    single = torch.is_tensor(observation)
    graph = OneStepGraph(policy, single).eval()
    torch.save(graph, path)
    named = {SINGLE: observation} if single else observation
    with torch.no_grad():
        difference = (torch.load(path, weights_only=False)(noise, named) - graph(noise, named)).abs().max().item()
    return {"file": path.name, "inputs": ["noise", *named], "max_abs_difference_to_pytorch": difference}


class PickledOneStepPolicy(nn.Module):
    """The format's runtime: the pickled module behind the FlowPolicy protocol, answering its one jump only."""

    def __init__(self, path: Path) -> None:
        super().__init__()
        self.graph = torch.load(path, weights_only=False)

    def encode(self, observation: Any) -> Any:
        return observation

    def velocity(self, x_t: Tensor, t: Tensor, s: Tensor, context: Any) -> Tensor:
        if not (bool((t == 1).all()) and bool((s == 0).all())):
            raise ValueError("a pickled one-step module answers only the jump from t = 1 to s = 0")
        observation = {SINGLE: context} if torch.is_tensor(context) else context
        return x_t - self.graph(x_t, observation)


@pytest.fixture
def pickle_format():
    register_export_format("pickle", "model.pt", f"{__name__}:export_pickled", f"{__name__}:PickledOneStepPolicy")
    yield EXPORT_FORMATS["pickle"]
    del EXPORT_FORMATS["pickle"]


def test_a_registered_format_exports_opens_and_refuses_like_the_built_in_one(tmp_path, pickle_format, capsys):
    student = _write_student(tmp_path / "student", "minivla")
    output = tmp_path / "pickled"
    assert main(["export", "--policy", str(student), "--format", "pickle", "--output", str(output)]) == 0
    assert (output / "model.pt").is_file()

    exported, eager = open_policy(output), open_policy(student)
    assert exported.export["format"] == "pickle" and exported.export["source"] == str(student)
    observation, noise = _batch(eager, 3)
    with torch.no_grad():
        expected = sample_actions(eager.policy, observation, noise, SNAPFLOW_1)
        torch.testing.assert_close(sample_actions(exported.policy, observation, noise, SNAPFLOW_1), expected)
    with pytest.raises(CheckpointError, match="is a pickle export of a one-step student: it runs snapflow-1 only"):
        exported.check_mode(TEACHER_10)
    assert main(["export", "--policy", str(output), "--format", "pickle", "--output", str(tmp_path / "again")]) == 2
    assert "is already an export (pickle)" in capsys.readouterr().err


def test_an_unregistered_format_is_not_offered(tmp_path, capsys):
    student = _write_student(tmp_path / "student", "mlp")
    with pytest.raises(SystemExit):
        main(["export", "--policy", str(student), "--format", "pickle", "--output", str(tmp_path / "out")])
    assert "invalid choice: 'pickle' (choose from 'onnx')" in capsys.readouterr().err
