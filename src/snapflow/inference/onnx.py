"""A one-step student as one ONNX graph, and that graph back as a policy.

The graph is the whole of SnapFlow 1-NFE inference: the prefix pass and the one jump from t = 1 to s = 0,
``actions = x_1 - F(x_1, s=0, t=1 | encode(observation))``, traced from the same solver that samples in PyTorch, so
no sampling loop is left in it. Its inputs are ``noise`` (B, chunk, action_dim) and the policy's observation tensors by
name, with the batch dimension free; its output is ``actions``. Any ONNX runtime (onnxruntime, TensorRT) runs it.

:class:`OnnxOneStepPolicy` runs such a file through onnxruntime behind the :class:`~snapflow.protocol.FlowPolicy`
protocol, so snapflow's evaluator and latency benchmark treat the exported student as they treat the PyTorch one. It
answers only the jump it was exported for (SnapFlow 1-NFE), and names any other request.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import Tensor, nn

from snapflow.errors import InvalidInputError
from snapflow.flow.modes import SNAPFLOW_1
from snapflow.flow.solver import euler_sample
from snapflow.protocol import FlowPolicy
from snapflow.reporting.files import atomic_write

SINGLE = "observation"  # the input name of an observation that is one tensor
OPSET = 18
#: the largest difference to PyTorch an export may show on its example (float32 arithmetic reordered)
TOLERANCE = 1e-4


class OneStepGraph(nn.Module):
    """``policy``'s SnapFlow 1-NFE generation as a module over (noise, named observation tensors): what is
    exported. A policy whose observation is one tensor reads it under the name :data:`SINGLE`."""

    def __init__(self, policy: FlowPolicy, single: bool) -> None:
        super().__init__()
        self.policy = policy
        self.single = single

    def forward(self, noise: Tensor, observation: dict[str, Tensor]) -> Tensor:
        context = self.policy.encode(observation[SINGLE] if self.single else observation)
        return euler_sample(lambda x, t, s: self.policy.velocity(x, t, s, context), noise, SNAPFLOW_1)


def _repeat_rows(tensors: dict[str, Tensor], rows: int) -> dict[str, Tensor]:
    return {name: tensor[:1].expand(rows, *tensor.shape[1:]).clone() for name, tensor in tensors.items()}


def export_onnx(
    policy: FlowPolicy, observation: Tensor | dict[str, Tensor], noise: Tensor, path: str | Path
) -> dict[str, Any]:
    """Write ``policy``'s one-step graph to ``path`` (one self-contained file, written whole or not at all), with the
    batch dimension free (or, where the policy's code pins it, traced at batch 1), checked against PyTorch on the
    example at batch 1 and 3. ``observation`` / ``noise``: one example of what the policy's processor gives it.
    Returns the export's record (file, inputs, outputs, opset, batch, the largest difference to PyTorch, versions);
    raises ``ValueError`` when the difference exceeds :data:`TOLERANCE`."""
    from importlib.metadata import version

    import onnxruntime  # noqa: F401 - fail before the export if the runtime is missing

    single = torch.is_tensor(observation)
    observation = {SINGLE: observation} if single else observation
    if not isinstance(observation, dict) or not all(torch.is_tensor(value) for value in observation.values()):
        raise ValueError("an exported policy's observation must be a tensor or a dict of tensors")
    graph = OneStepGraph(policy, single).eval()
    checked: dict[str, Any] = {"difference": 0.0}

    def export_and_check(temporary: Path) -> None:
        _trace(graph, observation, noise, temporary, free_batch=True)
        exported = OnnxOneStepPolicy(temporary)
        if exported.fixed_batch:  # the policy's code pins the batch somewhere: a graph for batch 1, run row by row
            _trace(graph, observation, noise, temporary, free_batch=False)
            exported = OnnxOneStepPolicy(temporary)
        for rows in (1, 3):
            example, example_noise = _repeat_rows(observation, rows), _repeat_rows({"noise": noise}, rows)["noise"]
            with torch.no_grad():
                expected = graph(example_noise, example)
            difference = (exported.actions(example, example_noise) - expected).abs().max().item()
            checked["difference"] = max(checked["difference"], difference)
        if not checked["difference"] <= TOLERANCE:
            raise ValueError(f"the ONNX graph differs from PyTorch by {checked['difference']:.2e} (> {TOLERANCE:.0e})")
        checked["batch"] = 1 if exported.fixed_batch else "free"

    atomic_write(path, export_and_check)
    return {
        "file": Path(path).name,
        "inputs": ["noise", *observation],
        "outputs": ["actions"],
        "opset": OPSET,
        "batch": checked["batch"],
        "max_abs_difference_to_pytorch": checked["difference"],
        "torch": torch.__version__,
        "onnxruntime": version("onnxruntime"),
    }


def _trace(graph: OneStepGraph, observation: dict[str, Tensor], noise: Tensor, path: Path, free_batch: bool) -> None:
    """torch.export -> ONNX of ``graph``: traced at batch 2 with the batch dimension free (a batch of 1 would be
    specialised into the graph), or at batch 1 with every shape fixed."""
    rows = 2 if free_batch else 1
    batch = torch.export.Dim("batch", min=1, max=4096)
    dynamic = {"noise": {0: batch}, "observation": {name: {0: batch} for name in observation}} if free_batch else None
    with torch.no_grad():
        torch.onnx.export(
            graph,
            (_repeat_rows({"noise": noise}, rows)["noise"],),
            str(path),
            kwargs={"observation": _repeat_rows(observation, rows)},
            input_names=["noise", *observation],
            output_names=["actions"],
            dynamic_shapes=dynamic,
            dynamo=True,
            opset_version=OPSET,
            external_data=False,
            verbose=False,
        )


class OnnxOneStepPolicy(nn.Module):
    """An exported one-step graph under the FlowPolicy protocol (onnxruntime, on the CPU).

    ``encode`` keeps the observation (the prefix runs inside the graph); ``velocity`` answers the jump t = 1 -> s = 0
    with the average velocity ``x_1 - actions``, so one Euler step of the shared solver returns the graph's actions.
    """

    compiled_methods = ()  # the graph is compiled already: compile_policy leaves it as it is

    def __init__(self, path: str | Path, threads: int | None = None) -> None:
        super().__init__()
        import onnxruntime

        options = onnxruntime.SessionOptions()
        options.intra_op_num_threads = threads or torch.get_num_threads()  # as many as PyTorch is given
        options.inter_op_num_threads = 1
        self.path = Path(path)
        self.session = onnxruntime.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])
        inputs = self.session.get_inputs()
        self.input_names = [entry.name for entry in inputs]
        #: a graph traced for batch 1 (the policy's code pins its batch): batches run through it row by row
        self.fixed_batch = any(not isinstance(entry.shape[0], str) for entry in inputs)

    def actions(self, observation: Tensor | dict[str, Any], noise: Tensor) -> Tensor:
        """The graph's action chunk for a batch of observations and noise."""
        observation = observation if isinstance(observation, dict) else {SINGLE: observation}
        feeds = {name: _numpy(observation[name]) for name in self.input_names if name != "noise"}
        feeds["noise"] = _numpy(noise)
        if not self.fixed_batch:
            return torch.from_numpy(self.session.run(["actions"], feeds)[0])
        rows = [
            self.session.run(["actions"], {name: value[row : row + 1] for name, value in feeds.items()})[0]
            for row in range(len(noise))
        ]
        return torch.from_numpy(np.concatenate(rows))

    def encode(self, observation: Tensor | dict[str, Any]) -> Tensor | dict[str, Any]:
        named = observation if isinstance(observation, dict) else {SINGLE: observation}
        missing = [name for name in self.input_names if name != "noise" and name not in named]
        if missing:
            raise InvalidInputError(f"{self.path} needs the observation entries {missing}")
        return observation

    def velocity(self, x_t: Tensor, t: Tensor, s: Tensor, context: dict[str, Any]) -> Tensor:
        if not (bool((t == 1).all()) and bool((s == 0).all())):
            raise InvalidInputError(
                f"{self.path} is a one-step graph: it answers only the jump from t = 1 to s = 0 (snapflow-1)"
            )
        return x_t - self.actions(context, x_t).to(x_t.dtype)


def _numpy(value: Any) -> np.ndarray:
    return value.detach().cpu().numpy() if torch.is_tensor(value) else np.asarray(value)


__all__ = ["SINGLE", "OPSET", "TOLERANCE", "OneStepGraph", "OnnxOneStepPolicy", "export_onnx"]
