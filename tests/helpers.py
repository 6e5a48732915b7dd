"""Test helpers: a small real policy, and a recorder that sees every call the objective makes."""

from __future__ import annotations

import copy
import os
import socket
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch
from torch import Tensor, nn

from snapflow.nn import SnapFlowPolicy
from snapflow.policies.mlp import MLPFlowModel, MLPPolicyConfig
from snapflow.protocol import Context

OBSERVATION_DIM, CHUNK, ACTION_DIM = 5, 3, 2


def make_model(seed: int = 0) -> MLPFlowModel:
    torch.manual_seed(seed)
    return MLPFlowModel(
        MLPPolicyConfig(
            observation_dim=OBSERVATION_DIM,
            action_dim=ACTION_DIM,
            chunk_length=CHUNK,
            hidden_dim=32,
            time_embedding_dim=16,
        )
    )


def randomise_target_time(policy: SnapFlowPolicy, seed: int = 1) -> SnapFlowPolicy:
    """Give phi_s a non-zero last layer, standing in for a partly trained student whose output depends on s."""
    generator = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for parameter in policy.target_time_embedding.linear_out.parameters():
            parameter.copy_(0.3 * torch.randn(parameter.shape, generator=generator))
    return policy


@dataclass
class Call:
    x: Tensor
    t: Tensor
    s: Tensor
    output: Tensor
    grad_enabled: bool


class RecordingPolicy(nn.Module):
    """Forwards to a real FlowPolicy and records each encode and velocity call.

    It is a module over the policy, so an objective may read ``training`` and ``parameters()`` through it; a deep copy
    (consistency distillation's EMA target network) is a copy of the policy alone, whose passes are not recorded.
    """

    def __init__(self, policy: nn.Module) -> None:
        super().__init__()
        self.policy = policy
        self.encodes = 0
        self.calls: list[Call] = []

    def __deepcopy__(self, memo: dict[int, Any]) -> nn.Module:
        return copy.deepcopy(self.policy, memo)

    def encode(self, observation: Any) -> Context:
        self.encodes += 1
        return self.policy.encode(observation)

    def velocity(self, x_t: Tensor, t: Tensor, s: Tensor, context: Context) -> Tensor:
        output = self.policy.velocity(x_t, t, s, context)
        inputs = (tensor.detach().clone() for tensor in (x_t, t, s))
        self.calls.append(Call(*inputs, output, torch.is_grad_enabled()))
        return output


def run_checked(
    command: list[str], environment: dict[str, str], cwd: Path | None = None, timeout: float = 900
) -> subprocess.CompletedProcess:
    """``command`` as a subprocess with ``environment`` added to this one's, no stdin, its output captured; it must
    exit 0, its stderr tail the failure message."""
    finished = subprocess.run(
        command,
        cwd=cwd,
        env={**os.environ, **environment},
        capture_output=True,
        text=True,
        stdin=subprocess.DEVNULL,
        timeout=timeout,
    )
    assert finished.returncode == 0, finished.stderr[-3000:]
    return finished


def run_short_lerobot_chain(folder: Path, bench: str) -> Path:
    """The LeRobot SmolVLA chain of the LeRobot guide (docs/guides/lerobot.md) in its short form (``SHORT=1 BENCH=<bench> scripts/lerobot-smolvla.sh``)
    into ``folder``, which it returns, keeping its checkpoints in ``folder/kept``; the chain's stderr tail is the
    failure message."""
    run_checked(
        ["bash", str(Path(__file__).resolve().parents[1] / "scripts" / "lerobot-smolvla.sh"), str(folder)],
        # the chain's python and snapflow are this interpreter's, whichever environment is first on PATH
        {
            "SHORT": "1",
            "BENCH": bench,
            "KEEP": str(folder / "kept"),
            "PATH": f"{Path(sys.executable).parent}{os.pathsep}{os.environ['PATH']}",
        },
        timeout=1800,
    )
    return folder


def run_tiny_lerobot_train(
    student: Path, data: Path, output: Path, steps: int, batch_size: int, *flags: str, cwd: Path | None = None
) -> Path:
    """``lerobot-train`` itself, offline on the CPU, on the tiny dataset at ``data``, started in ``cwd`` (default:
    this process's working directory, which relative paths are read from); checks it ran SnapFlow's objective and
    returns its last checkpoint's policy folder."""
    finished = run_checked(
        [
            str(Path(sys.executable).with_name("lerobot-train")),
            f"--policy.path={student}",
            "--dataset.repo_id=local/tiny",
            f"--dataset.root={data}",
            f"--output_dir={output}",
            f"--steps={steps}",
            f"--batch_size={batch_size}",
            "--num_workers=0",
            f"--save_freq={steps}",
            "--wandb.enable=false",
            "--policy.device=cpu",
            "--policy.push_to_hub=false",
            *flags,
        ],
        {"HF_HUB_OFFLINE": "1"},
        cwd=cwd,
    )
    assert "consistency_loss" in finished.stderr, "LeRobot logs the objective's parts"
    return output / "checkpoints" / "last" / "pretrained_model"


def run_in_policy_folder(folder: Path, command: list[str]) -> subprocess.CompletedProcess:
    """A LeRobot command (``lerobot-eval`` and its arguments, say) run from inside the policy folder ``folder``, as a
    user runs it with ``--policy.path=.``: off-screen rendering; its stderr tail is the failure message."""
    return run_checked(command, {"MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")}, cwd=folder)


def free_loopback_port() -> int:
    """A port on the loopback that nothing listens on now, for a server a test starts."""
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]
