"""What a distillation target costs: seconds per training step of each SnapFlow target, timed round-robin.

Every option trains a copy of the same student (the teacher plus a fresh phi_s, prefix frozen as in
``snapflow distill``) on the same batch, one full step each (objective, backward, AdamW), interleaved so that
a noisy machine slows all options alike; medians after warm-up. A schedule is timed at each of its stages in
turn, so its median is that of the mixture of stages training goes through.
"""

from __future__ import annotations

import copy
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch

from snapflow.data.chunks import split_chunk_data
from snapflow.data.demonstrations import Demonstrations
from snapflow.flow.time_sampling import TimeSampler
from snapflow.nn.snapflow_policy import SnapFlowPolicy
from snapflow.objective.options import PAPER_TARGET_STEPS, target_stages
from snapflow.policies.checkpoint import load_policy
from snapflow.protocol import map_tensors
from snapflow.reporting.files import write_json, write_text
from snapflow.reporting.machine import machine
from snapflow.reporting.tables import markdown_table
from snapflow.training.config import PAPER_STUDENT_TRAINING
from snapflow.training.recipes import TargetOption
from snapflow.training.trainer import ObjectiveModule, train_step


def time_training_steps(
    student: SnapFlowPolicy,
    observation: Any,
    actions: torch.Tensor,
    options: list[TargetOption],
    time_sampler: TimeSampler,
    freeze_prefix: bool = True,
    warmup: int = 5,
    repeats: int = 30,
    learning_rate: float = PAPER_STUDENT_TRAINING.learning_rate,
    copy_student: bool = True,
) -> dict[str, Any]:
    """Median and P90 seconds of one training step (:func:`snapflow.training.trainer.train_step`) per option; with
    ``freeze_prefix`` the optimiser updates the student's ``expert_parameters()``, as ``snapflow distill`` does.
    The student is copied per option, so the options never see each other's updates (with one option and
    ``copy_student=False`` it trains in place: no second copy in memory)."""
    if not options:
        raise ValueError("time at least one target option")
    if warmup < 0 or repeats < 1:
        raise ValueError(f"need warmup >= 0 and repeats >= 1, got {warmup} and {repeats}")
    runners = []
    for option in options:
        policy = copy.deepcopy(student) if copy_student or len(options) > 1 else student
        parameters = policy.expert_parameters() if freeze_prefix else list(policy.parameters())
        optimizer = torch.optim.AdamW(parameters, lr=learning_rate)
        runners.append((option, ObjectiveModule(policy, option.settings().objective(time_sampler)), optimizer))
    generator = torch.Generator().manual_seed(0)
    stages = {option: len(target_stages(option.steps)) for option in options}
    times: dict[TargetOption, list[float]] = {option: [] for option in options}
    for repeat in range(warmup + repeats):
        for option, module, optimizer in runners:
            progress = (repeat % stages[option] + 0.5) / stages[option]
            started = time.perf_counter()
            train_step(
                module,
                optimizer,
                observation,
                actions,
                learning_rate=learning_rate,
                generator=generator,
                progress=progress,
            )
            elapsed = time.perf_counter() - started
            if repeat >= warmup:
                times[option].append(elapsed)
    reference = float(np.median(times[options[0]]))
    rows = [
        {
            "option": option.name,
            "label": option.label,
            "teacher_passes_per_row": option.teacher_passes,
            "step_ms_median": 1000 * float(np.median(times[option])),
            "step_ms_p90": 1000 * float(np.percentile(times[option], 90)),
            "relative_to_first": float(np.median(times[option])) / reference,
        }
        for option in options
    ]
    return {
        "batch_size": int(actions.shape[0]),
        "warmup": warmup,
        "repeats": repeats,
        "machine": machine(),
        "rows": rows,
    }


def checkpoint_training_cost(
    teacher: str | Path,
    data: str | Path,
    options: list[TargetOption],
    batch_size: int = 64,
    warmup: int = 5,
    repeats: int = 30,
) -> dict[str, Any]:
    """:func:`time_training_steps` for the student of a built-in ``teacher`` checkpoint (phi_s added, prefix frozen, as
    ``snapflow distill`` trains it) on one batch of its training demonstrations, with the teacher and the data named."""
    loaded = load_policy(teacher, target_time=True)
    train_data, _ = split_chunk_data(Demonstrations.load(data), loaded.processor, loaded.val_fraction)
    observation, actions = train_data.batch(
        torch.randint(len(train_data), (batch_size,), generator=torch.Generator().manual_seed(0))
    )
    timed = time_training_steps(
        loaded.policy, observation, actions, options, loaded.time_sampler, warmup=warmup, repeats=repeats
    )
    return {**timed, "teacher": str(teacher), "data": str(data)}


def _peak_memory_gib(device: torch.device) -> float:
    """Peak memory so far: allocated on a GPU (reset per batch size), the process's peak resident set elsewhere."""
    if device.type == "cuda":
        return torch.cuda.max_memory_allocated(device) / 2**30
    import resource

    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20  # KiB on Linux


def distillation_step_cost(
    student: Any,
    observation: Any,
    noise: torch.Tensor,
    batch_sizes: tuple[int, ...],
    time_sampler: TimeSampler,
    warmup: int = 3,
    repeats: int = 10,
) -> dict[str, Any]:
    """ms per distillation step (the paper's objective and target, backward, AdamW on ``expert_parameters()``) and
    peak memory at each batch size, on the batch-1 ``observation`` repeated and random actions shaped as ``noise``: what a full-size run
    costs, to plan it. The student trains in place (its weights move; timing does not depend on them)."""
    device = noise.device
    rows = []
    for size in batch_sizes:
        batch = map_tensors(observation, lambda tensor, size=size: tensor[:1].expand(size, *tensor.shape[1:]).clone())
        actions = torch.randn(size, *noise.shape[1:], device=device, dtype=noise.dtype)
        if device.type == "cuda":
            torch.cuda.reset_peak_memory_stats(device)
        paper_target = [TargetOption("euler", PAPER_TARGET_STEPS)]
        timed = time_training_steps(
            student, batch, actions, paper_target, time_sampler, warmup=warmup, repeats=repeats, copy_student=False
        )
        row = timed["rows"][0]
        rows.append(
            {
                "batch_size": size,
                "step_ms_median": row["step_ms_median"],
                "step_ms_p90": row["step_ms_p90"],
                "peak_memory_gib": _peak_memory_gib(device),
            }
        )
    return {
        "warmup": warmup,
        "repeats": repeats,
        "peak_memory": "allocated on the GPU" if device.type == "cuda" else "process peak resident set",
        "rows": rows,
    }


def markdown_training_cost(result: dict[str, Any]) -> str:
    first = result["rows"][0]["label"]
    lines = [
        f"One distillation step (objective, backward, AdamW) at batch {result['batch_size']}, median and P90 of {result['repeats']} "
        f"round-robin repeats after {result['warmup']} warm-up steps; {result['machine']['cpu']}, {result['machine']['threads']} thread(s), "
        f"torch {result['machine']['torch']}.",
        "",
        markdown_table(
            ["target", "no-grad passes per one-step row", "ms per step (median)", "P90", f"/ {first}"],
            [
                [
                    row["label"],
                    f"{row['teacher_passes_per_row']:.3g} + 1",
                    f"{row['step_ms_median']:.1f}",
                    f"{row['step_ms_p90']:.1f}",
                    f"{row['relative_to_first']:.2f}x",
                ]
                for row in result["rows"]
            ],
        ),
    ]
    return "\n".join(lines)


def write_training_cost(result: dict[str, Any], output: str | Path) -> None:
    """``training_cost.json`` and its table, ``training_cost.md``, in ``output``."""
    output = Path(output)
    write_json(output / "training_cost.json", result)
    write_text(output / "training_cost.md", markdown_training_cost(result) + "\n")


__all__ = [
    "checkpoint_training_cost",
    "distillation_step_cost",
    "markdown_training_cost",
    "time_training_steps",
    "write_training_cost",
]
