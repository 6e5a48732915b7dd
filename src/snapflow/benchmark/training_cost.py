"""What a distillation target costs: seconds per training step of each SnapFlow target, timed round-robin.

Every option trains a copy of the same student (the teacher plus a fresh phi_s, prefix frozen as in
``snapflow distill``) on the same batch, one full step each (objective, backward, AdamW), interleaved so that
a noisy machine slows all options alike; medians after warm-up. A schedule is timed at each of its stages in
turn, so its median is that of the mixture of stages training goes through.
"""

from __future__ import annotations

import copy
import time
from typing import Any

import numpy as np
import torch

from snapflow.benchmark.latency import machine
from snapflow.flow.time_sampling import TimeSampler
from snapflow.nn.snapflow_policy import SnapFlowPolicy
from snapflow.objective.snapflow import target_stages
from snapflow.training.distill import TargetOption


def time_training_steps(
    student: SnapFlowPolicy, observation: Any, actions: torch.Tensor, options: list[TargetOption], time_sampler: TimeSampler,
    trainable: list[str] | None = None, warmup: int = 5, repeats: int = 30, learning_rate: float = 3e-5,
) -> dict[str, Any]:
    """Median and P90 seconds of one training step per option; ``trainable`` names the parameters the optimiser
    updates (default: all). The student is copied per option, so the options never see each other's updates."""
    if not options:
        raise ValueError("time at least one target option")
    if warmup < 0 or repeats < 1:
        raise ValueError(f"need warmup >= 0 and repeats >= 1, got {warmup} and {repeats}")
    runners = []
    for option in options:
        policy = copy.deepcopy(student).train()
        parameters = [p for name, p in policy.named_parameters() if trainable is None or name in trainable]
        optimizer = torch.optim.AdamW(parameters, lr=learning_rate)
        runners.append((option, policy, option.settings().objective(time_sampler), optimizer))
    generator = torch.Generator().manual_seed(0)
    stages = {option: len(target_stages(option.steps)) for option in options}
    times: dict[TargetOption, list[float]] = {option: [] for option in options}
    for repeat in range(warmup + repeats):
        for option, policy, objective, optimizer in runners:
            progress = (repeat % stages[option] + 0.5) / stages[option]
            started = time.perf_counter()
            loss = objective(policy, observation, actions, generator=generator, progress=progress).loss
            optimizer.zero_grad(set_to_none=True)
            loss.backward()
            optimizer.step()
            elapsed = time.perf_counter() - started
            if repeat >= warmup:
                times[option].append(elapsed)
    reference = float(np.median(times[options[0]]))
    rows = [{
        "option": option.name, "label": option.label, "teacher_passes_per_row": option.teacher_passes,
        "step_ms_median": 1000 * float(np.median(times[option])), "step_ms_p90": 1000 * float(np.percentile(times[option], 90)),
        "relative_to_first": float(np.median(times[option])) / reference,
    } for option in options]
    return {"batch_size": int(actions.shape[0]), "warmup": warmup, "repeats": repeats, "machine": machine(), "rows": rows}


def markdown_training_cost(result: dict[str, Any]) -> str:
    first = result["rows"][0]["label"]
    lines = [
        f"One distillation step (objective, backward, AdamW) at batch {result['batch_size']}, median and P90 of {result['repeats']} "
        f"round-robin repeats after {result['warmup']} warm-up steps; {result['machine']['cpu']}, {result['machine']['threads']} thread(s), "
        f"torch {result['machine']['torch']}.",
        "",
        f"| target | no-grad passes per one-step row | ms per step (median) | P90 | / {first} |",
        "|---|---|---|---|---|",
    ]
    for row in result["rows"]:
        lines.append(f"| {row['label']} | {row['teacher_passes_per_row']:.3g} + 1 | {row['step_ms_median']:.1f} | {row['step_ms_p90']:.1f} | "
                     f"{row['relative_to_first']:.2f}x |")
    return "\n".join(lines)


__all__ = ["markdown_training_cost", "time_training_steps"]
