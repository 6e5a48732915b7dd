"""``snapflow toy``: the paper's story in miniature, on a conditional Gaussian mixture whose samples are exact.

Train a flow-matching teacher, SnapFlow-distill it, then compare the 10-step teacher, the naive 1-step teacher
(which collapses onto the conditional mean) and SnapFlow 1-NFE by their energy distance to the data and their mode
coverage (per observation, the share of samples in each mode against the true one). ``ToyConfig.shape`` picks the
distribution (:mod:`snapflow.data.toy_shapes`).
"""

from __future__ import annotations

import copy
import time
from dataclasses import dataclass, field
from pathlib import Path

import torch
from torch import Tensor
from tqdm.auto import tqdm

from snapflow.data.toy_shapes import ToyShape
from snapflow.evaluation.distances import coverage_error, energy_distance, mode_shares
from snapflow.flow.modes import NAIVE_1, SNAPFLOW_1, STANDARD_MODES, TEACHER_10
from snapflow.flow.solver import sample_actions
from snapflow.flow.time_sampling import UniformTimeSampler
from snapflow.jobs.toy_config import ToyConfig
from snapflow.nn.snapflow_policy import SnapFlowPolicy
from snapflow.objective.base import TwoBranchObjective
from snapflow.objective.snapflow import SnapFlowObjective
from snapflow.policies.mlp import MLPFlowModel, MLPPolicyConfig
from snapflow.reporting.figures import pyplot, save_figure
from snapflow.reporting.tables import markdown_table
from snapflow.training.config import TrainConfig
from snapflow.training.trainer import ObjectiveModule, train_step


@dataclass
class ToyResult:
    """Mean energy distance to exact samples per sampling mode, the distillation's seconds per step, each sampler's
    mode coverage (``coverage``: its :func:`~snapflow.evaluation.distances.coverage_error`; ``shares``: per evaluation
    context, the share of samples in each mode and, last, off every mode; ``data`` the exact samples' own), and what
    is needed to plot them."""

    config: ToyConfig
    distances: dict[str, float]
    distill_step_s: float
    eval_contexts: Tensor
    data_samples: Tensor = field(repr=False)
    model_samples: dict[str, Tensor] = field(repr=False)
    coverage: dict[str, float] = field(default_factory=dict)
    shares: dict[str, list[list[float]]] = field(default_factory=dict, repr=False)
    true_weights: list[list[float]] = field(default_factory=list, repr=False)

    def to_dict(self) -> dict:
        return {
            "config": self.config.record(),
            "energy_distance": self.distances,
            "distill_step_s": self.distill_step_s,
            "coverage_error": self.coverage,
            "mode_shares": self.shares,
            "true_mode_weights": self.true_weights,
        }


def _fit(
    policy: SnapFlowPolicy,
    trainable: list[torch.nn.Parameter],
    objective: TwoBranchObjective,
    mixture: ToyShape,
    config: TrainConfig,
    generator: torch.Generator,
    description: str,
    progress: bool,
) -> float:
    """The trainer's step (AdamW on ``trainable``, cosine-decayed learning rate) on fresh exact samples at every step;
    returns seconds per step."""
    module = ObjectiveModule(policy, objective)
    optimizer = torch.optim.AdamW(trainable, lr=config.learning_rate, weight_decay=config.weight_decay)
    bar = tqdm(range(config.steps), desc=description, disable=not progress, leave=False)
    started = time.perf_counter()
    for step in bar:
        context = mixture.sample_contexts(config.batch_size, generator)
        actions = mixture.sample(context, generator)[:, None, :]
        losses = train_step(
            module,
            optimizer,
            context,
            actions,
            learning_rate=config.learning_rate_at(step),
            grad_clip=config.grad_clip,
            generator=generator,
            progress=step / config.steps,
        )
        if step % 50 == 0:
            bar.set_postfix(fm=f"{losses[1].item():.3f}", sc=f"{losses[2].item():.4f}", refresh=False)
    return (time.perf_counter() - started) / config.steps


def _schedule(steps: int, learning_rate: float, batch_size: int) -> TrainConfig:
    """The toy's optimisation: cosine decay to zero from the first step, no warm-up, no gradient clipping."""
    return TrainConfig(
        steps=steps,
        batch_size=batch_size,
        learning_rate=learning_rate,
        warmup_steps=0,
        min_learning_rate_ratio=0.0,
        grad_clip=0.0,
    )


def run_toy_experiment(config: ToyConfig | None = None, progress: bool = True) -> ToyResult:
    """Train a teacher with flow matching, distill it with ``config.distill`` (SnapFlow or a baseline; the observation
    encoder frozen where ``freeze_prefix``, no phi_s where not ``target_time``), score every sampling mode; the
    one-step jump of the distilled student is reported as ``snapflow-1`` whatever the method."""
    config = config or ToyConfig()
    torch.manual_seed(config.seed)
    generator = torch.Generator().manual_seed(config.seed)
    mixture = ToyShape(config.shape, config.num_modes, config.mode_radius)
    model = MLPFlowModel(
        MLPPolicyConfig(observation_dim=mixture.context_dim, action_dim=2, hidden_dim=config.hidden_dim)
    )
    teacher = SnapFlowPolicy(model, target_time=False)
    time_sampler = UniformTimeSampler()
    _fit(
        teacher,
        list(teacher.parameters()),
        SnapFlowObjective(alpha=1.0, time_sampler=time_sampler),
        mixture,
        _schedule(config.teacher_steps, config.teacher_lr, config.batch_size),
        generator,
        "teacher (flow matching)",
        progress,
    )

    settings = config.distill
    student = SnapFlowPolicy(copy.deepcopy(model), target_time=settings.target_time)
    step_s = _fit(
        student,
        student.expert_parameters() if settings.freeze_prefix else list(student.parameters()),
        settings.objective(time_sampler),
        mixture,
        _schedule(config.distill_steps, config.distill_lr, config.batch_size),
        generator,
        f"{settings.method} distillation",
        progress,
    )

    eval_generator = torch.Generator().manual_seed(config.seed + 1)
    contexts = mixture.sample_contexts(config.eval_contexts, eval_generator)
    repeated = contexts.repeat_interleave(config.samples_per_context, dim=0)
    data = mixture.sample(repeated, eval_generator).view(config.eval_contexts, config.samples_per_context, 2)
    noise = torch.randn(len(repeated), 1, 2, generator=eval_generator)
    samples, distances = {}, {}
    for mode in STANDARD_MODES:
        policy = student if mode.jump else teacher
        chunk = sample_actions(policy, repeated, noise, mode)
        samples[mode.name] = chunk.view(config.eval_contexts, config.samples_per_context, 2)
        distances[mode.name] = (
            torch.stack([energy_distance(samples[mode.name][i], data[i]) for i in range(config.eval_contexts)])
            .mean()
            .item()
        )
    weights = mixture.mode_weights(contexts)
    coverage, shares = {}, {}
    for name, points in {"data": data, **samples}.items():
        share = mode_shares(mixture.mode_of(points.reshape(-1, 2)).view(points.shape[:2]), mixture.num_modes)
        coverage[name], shares[name] = coverage_error(share, weights).item(), share.tolist()
    return ToyResult(config, distances, step_s, contexts, data, samples, coverage, shares, weights.tolist())


def markdown_toy(result: ToyResult) -> str:
    """What the toy measured, then each sampler's energy distance, also relative to the naive one step."""
    config = result.config
    naive = result.distances[NAIVE_1.name]
    method = config.distill.method
    student = "SnapFlow 1-NFE" if method == "snapflow" else f"{method} 1-NFE"
    rows = [("teacher 10-NFE", TEACHER_10.name, 10), ("naive 1-NFE", NAIVE_1.name, 1), (student, SNAPFLOW_1.name, 1)]
    table = markdown_table(
        ["sampler", "NFE", "energy distance", "/ naive 1-NFE", "coverage error"],
        [
            [
                label,
                nfe,
                f"{result.distances[key]:.4f}",
                f"{result.distances[key] / naive:.3f}",
                f"{result.coverage[key]:.3f}",
            ]
            for label, key, nfe in rows
        ],
    )
    shape = "Conditional Gaussian mixture" if config.shape == "mixture" else "Conditional two rings"
    return (
        f"{shape}, seed {config.seed}: {config.eval_contexts} contexts x {config.samples_per_context} samples, energy "
        "distance to exact samples and coverage error (the total variation between the samples' shares of the modes "
        f"and the true weights; exact samples {result.coverage['data']:.3f}), lower is better\n\n{table}"
    )


def plot_toy_result(result: ToyResult, path: Path, num_contexts: int = 3) -> None:
    """PNG grid: one row per evaluation context, the exact data then each sampling mode."""
    plt = pyplot()
    method = result.config.distill.method

    def label(name: str) -> str:  # the student's one-step jump, named after the objective that trained it
        return f"{method} 1-NFE" if name == SNAPFLOW_1.name and method != "snapflow" else name

    columns = [("data (exact)", result.data_samples)] + [
        (f"{label(name)}  ED={result.distances[name]:.3f}", samples) for name, samples in result.model_samples.items()
    ]
    rows = min(num_contexts, len(result.eval_contexts))
    figure, axes = plt.subplots(rows, len(columns), figsize=(3.2 * len(columns), 3.2 * rows), squeeze=False)
    for row in range(rows):
        for column, (title, samples) in enumerate(columns):
            axis = axes[row][column]
            points = samples[row].numpy()
            axis.scatter(points[:, 0], points[:, 1], s=3, alpha=0.5, color="black" if column == 0 else f"C{column}")
            axis.set_xlim(-3, 3)
            axis.set_ylim(-3, 3)
            axis.set_aspect("equal")
            axis.set_xticks([])
            axis.set_yticks([])
            if row == 0:
                axis.set_title(title, fontsize=9)
        axes[row][0].set_ylabel(f"context {row}")
    figure.suptitle("Conditional Gaussian mixture: samples per mode (ED = mean energy distance to data)")
    figure.tight_layout()
    save_figure(figure, path)


__all__ = ["ToyConfig", "ToyResult", "run_toy_experiment", "markdown_toy", "plot_toy_result"]
