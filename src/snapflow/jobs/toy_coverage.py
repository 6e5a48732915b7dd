"""Mode coverage on the toy, drawn, and what a distillation step costs, timed fairly.

:func:`plot_coverage` draws, for a few evaluation contexts, each sampler's share of samples in each mode beside the
true weights (from the run records of :mod:`snapflow.jobs.toy_compare`). :func:`step_costs` times the distillation
step of several settings round-robin, block by block, so that a machine whose load drifts slows them alike, in the
CPU time of the timing process, which other processes on a shared machine do not inflate as they do the wall clock.
"""

from __future__ import annotations

import copy
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch

from snapflow.data.toy_shapes import ToyShape
from snapflow.flow.modes import NAIVE_1, SNAPFLOW_1, TEACHER_10
from snapflow.flow.time_sampling import UniformTimeSampler
from snapflow.jobs.toy_config import ToyConfig
from snapflow.nn.snapflow_policy import SnapFlowPolicy
from snapflow.policies.mlp import MLPFlowModel, MLPPolicyConfig
from snapflow.reporting.figures import pyplot, save_figure
from snapflow.training.trainer import ObjectiveModule, train_step

#: the distillation steps timed in one block of a round
BLOCK_STEPS = 20


def step_costs(configs: dict[str, ToyConfig], repeats: int, block: int = BLOCK_STEPS) -> dict[str, float]:
    """Median milliseconds of one distillation step under each named config, over ``repeats`` rounds that each time a
    block of ``block`` steps of every config in turn (after one untimed block each), in CPU time of this process
    (summed over its threads: run it on one torch thread for a step's latency). The student starts from an untrained
    teacher: a step's cost does not depend on the weights."""
    if repeats < 1 or block < 1:
        raise ValueError(f"time at least one round of one step, got {repeats} rounds of {block}")
    steppers = {name: _stepper(config) for name, config in configs.items()}
    for step in steppers.values():
        step(block)
    timings: dict[str, list[float]] = {name: [] for name in configs}
    for _ in range(repeats):
        for name, step in steppers.items():
            started = time.process_time()
            step(block)
            timings[name].append(1000 * (time.process_time() - started) / block)
    return {name: float(np.median(values)) for name, values in timings.items()}


def _stepper(config: ToyConfig) -> Any:
    """A function that takes ``n`` distillation steps of ``config`` as the toy run takes them (fresh exact samples
    every step, AdamW)."""
    torch.manual_seed(config.seed)
    generator = torch.Generator().manual_seed(config.seed)
    shape = ToyShape(config.shape, config.num_modes, config.mode_radius)
    model = MLPFlowModel(MLPPolicyConfig(observation_dim=shape.context_dim, action_dim=2, hidden_dim=config.hidden_dim))
    settings = config.distill
    student = SnapFlowPolicy(copy.deepcopy(model), target_time=settings.target_time)
    module = ObjectiveModule(student, settings.objective(UniformTimeSampler()))
    trainable = student.expert_parameters() if settings.freeze_prefix else list(student.parameters())
    optimizer = torch.optim.AdamW(trainable, lr=config.distill_lr)

    def step(n: int) -> None:
        for _ in range(n):
            context = shape.sample_contexts(config.batch_size, generator)
            actions = shape.sample(context, generator)[:, None, :]
            train_step(module, optimizer, context, actions, learning_rate=config.distill_lr, generator=generator)

    return step


def plot_coverage(runs: dict[str, dict[str, Any]], path: Path, contexts: int = 4) -> None:
    """Stacked bars, one panel per evaluation context: the true mode weights, the 10-step teacher's, the naive step's
    and each labelled run's one-step shares (``runs``: label -> a run record of one seed, every run on the same
    contexts), each mode a colour and the share off every mode grey."""
    plt = pyplot()
    first = next(iter(runs.values()))
    truth = np.asarray(first["true_mode_weights"])
    shown = min(contexts, len(truth))
    bars = [("true", np.concatenate([truth, np.zeros((len(truth), 1))], axis=1))]
    bars += [(name, np.asarray(first["mode_shares"][name])) for name in (TEACHER_10.name, NAIVE_1.name)]
    bars += [(label, np.asarray(run["mode_shares"][SNAPFLOW_1.name])) for label, run in runs.items()]
    modes = truth.shape[1]
    colours = [f"C{k}" for k in range(modes)] + ["0.7"]
    columns = min(shown, 2)
    grid = (-(-shown // columns), columns)
    figure, axes = plt.subplots(*grid, figsize=(0.7 * len(bars) * columns + 1.5, 3.4 * grid[0] + 0.8), squeeze=False)
    for panel in range(grid[0] * grid[1]):
        axis = axes[panel // columns][panel % columns]
        if panel >= shown:
            axis.set_visible(False)
            continue
        bottom = np.zeros(len(bars))
        for k in range(modes + 1):
            heights = np.array([shares[panel][k] for _, shares in bars])
            label = f"mode {k}" if k < modes else "off every mode"
            axis.bar(range(len(bars)), heights, bottom=bottom, color=colours[k], label=label if panel == 0 else None)
            bottom += heights
        axis.set_xticks(range(len(bars)), [label for label, _ in bars], rotation=30, ha="right", fontsize=7)
        axis.set_ylim(0, 1)
        axis.set_title(f"context {panel}", fontsize=9)
        axis.set_ylabel("share of samples", fontsize=8)
    figure.legend(loc="upper center", ncol=modes + 1, fontsize=7)
    figure.suptitle("Mode coverage per context (seed of the first run)", fontsize=9, y=0.95)
    figure.tight_layout(rect=(0, 0, 1, 0.93))
    save_figure(figure, path, dpi=120)


__all__ = ["BLOCK_STEPS", "plot_coverage", "step_costs"]
