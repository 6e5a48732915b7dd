"""A conditional problem with a known answer: 2-D Gaussian mixtures whose mode weights depend on a context.

Exact samples are free, so every sampling mode can be scored by its energy distance to the data. The
story is the paper's in miniature: train a flow-matching teacher, SnapFlow-distill it, then compare the
10-step teacher, the naive 1-step teacher (which collapses onto the conditional mean) and SnapFlow 1-NFE.
"""

from __future__ import annotations

import copy
import math
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import torch
from torch import Tensor
from tqdm.auto import tqdm

from snapflow.evaluation.distances import energy_distance
from snapflow.flow.solver import NAIVE_1, SNAPFLOW_1, TEACHER_10, SamplingMode, sample_actions
from snapflow.flow.time_sampling import UniformTimeSampler
from snapflow.evaluation.report import pyplot
from snapflow.io import atomic_write
from snapflow.nn.snapflow_policy import SnapFlowPolicy
from snapflow.objective.snapflow import SnapFlowObjective
from snapflow.training.distill import DistillSettings
from snapflow.policies.mlp import MLPFlowModel, MLPPolicyConfig


class ConditionalGaussianMixture:
    """p(a | c) = sum_k softmax(gain * W c)_k N(mu_k, std^2 I), modes evenly spaced on a circle.

    Contexts are c ~ N(0, I). ``W`` is fixed by ``seed``, so the distribution is the same on every machine.
    """

    def __init__(
        self, num_modes: int = 6, context_dim: int = 4, radius: float = 2.0, mode_std: float = 0.12,
        weight_gain: float = 2.0, seed: int = 0,
    ) -> None:
        angles = torch.arange(num_modes, dtype=torch.float32) * (2 * math.pi / num_modes)
        self.means = radius * torch.stack([angles.cos(), angles.sin()], dim=1)
        self.mode_std = mode_std
        self.context_dim = context_dim
        self.logit_map = weight_gain * torch.randn(num_modes, context_dim, generator=torch.Generator().manual_seed(seed))

    def mode_weights(self, context: Tensor) -> Tensor:
        return torch.softmax(context @ self.logit_map.T, dim=1)

    def sample_contexts(self, n: int, generator: torch.Generator | None = None) -> Tensor:
        return torch.randn(n, self.context_dim, generator=generator)

    def sample(self, context: Tensor, generator: torch.Generator | None = None) -> Tensor:
        """One exact sample a ~ p(a | c) per context row, shape (B, 2)."""
        modes = torch.multinomial(self.mode_weights(context), 1, generator=generator).squeeze(1)
        return self.means[modes] + self.mode_std * torch.randn(len(modes), 2, generator=generator)


@dataclass(frozen=True)
class ToyConfig:
    """Sizes and schedules of the toy experiment; the defaults run in well under a minute on 2 cores."""

    seed: int = 0
    num_modes: int = 6
    mode_radius: float = 2.0
    teacher_steps: int = 1500
    distill_steps: int = 3000
    batch_size: int = 256
    teacher_lr: float = 2e-3
    distill_lr: float = 1e-3
    alpha: float = 0.5
    consistency_weight: float = 0.1
    method: str = "snapflow"  # or a one-step baseline, see snapflow.training.distill.METHODS
    target: str = "euler"  # SnapFlow's target and its steps (a list: a schedule), see DistillSettings
    target_steps: int | tuple[int, ...] = 2
    hidden_dim: int = 256
    eval_contexts: int = 12
    samples_per_context: int = 400


@dataclass
class ToyResult:
    """Mean energy distance to exact samples per sampling mode, the distillation's seconds per step, and
    what is needed to plot them."""

    config: ToyConfig
    distances: dict[str, float]
    distill_step_s: float
    eval_contexts: Tensor
    data_samples: Tensor = field(repr=False)
    model_samples: dict[str, Tensor] = field(repr=False)

    def to_dict(self) -> dict:
        return {"config": asdict(self.config), "energy_distance": self.distances, "distill_step_s": self.distill_step_s}


MODES: tuple[SamplingMode, ...] = (TEACHER_10, NAIVE_1, SNAPFLOW_1)


def _fit(policy, objective, mixture, steps, lr, batch_size, generator, description, progress) -> float:
    """Adam with a cosine-decayed learning rate on fresh exact samples at every step; returns seconds per step."""
    optimizer = torch.optim.AdamW(policy.parameters(), lr=lr, weight_decay=0.0)
    schedule = torch.optim.lr_scheduler.CosineAnnealingLR(optimizer, steps)
    bar = tqdm(range(steps), desc=description, disable=not progress, leave=False)
    started = time.perf_counter()
    for step in bar:
        context = mixture.sample_contexts(batch_size, generator)
        actions = mixture.sample(context, generator)[:, None, :]
        output = objective(policy, context, actions, generator=generator, progress=step / steps)
        optimizer.zero_grad(set_to_none=True)
        output.loss.backward()
        optimizer.step()
        schedule.step()
        if step % 50 == 0:
            bar.set_postfix(fm=f"{output.flow_matching_loss.item():.3f}", sc=f"{output.consistency_loss.item():.4f}", refresh=False)
    return (time.perf_counter() - started) / steps


def run_toy_experiment(config: ToyConfig = ToyConfig(), progress: bool = True) -> ToyResult:
    """Train a teacher with flow matching, distill it (SnapFlow or ``config.method``), score every sampling mode;
    the one-step jump of the distilled student is reported as ``snapflow-1`` whatever the method."""
    torch.manual_seed(config.seed)
    generator = torch.Generator().manual_seed(config.seed)
    mixture = ConditionalGaussianMixture(num_modes=config.num_modes, radius=config.mode_radius)
    model = MLPFlowModel(MLPPolicyConfig(observation_dim=mixture.context_dim, action_dim=2, hidden_dim=config.hidden_dim))
    teacher = SnapFlowPolicy(model, target_time=False)
    time_sampler = UniformTimeSampler()
    _fit(teacher, SnapFlowObjective(alpha=1.0, time_sampler=time_sampler), mixture, config.teacher_steps,
         config.teacher_lr, config.batch_size, generator, "teacher (flow matching)", progress)

    student = SnapFlowPolicy(copy.deepcopy(model), target_time=True)
    settings = DistillSettings(config.alpha, config.consistency_weight, method=config.method, target=config.target, target_steps=config.target_steps)
    step_s = _fit(student, settings.objective(time_sampler), mixture, config.distill_steps, config.distill_lr, config.batch_size, generator,
                  f"{config.method} distillation", progress)

    eval_generator = torch.Generator().manual_seed(config.seed + 1)
    contexts = mixture.sample_contexts(config.eval_contexts, eval_generator)
    repeated = contexts.repeat_interleave(config.samples_per_context, dim=0)
    data = mixture.sample(repeated, eval_generator).view(config.eval_contexts, config.samples_per_context, 2)
    noise = torch.randn(len(repeated), 1, 2, generator=eval_generator)
    samples, distances = {}, {}
    for mode in MODES:
        policy = student if mode.jump else teacher
        chunk = sample_actions(policy, repeated, noise, mode)
        samples[mode.name] = chunk.view(config.eval_contexts, config.samples_per_context, 2)
        distances[mode.name] = torch.stack(
            [energy_distance(samples[mode.name][i], data[i]) for i in range(config.eval_contexts)]
        ).mean().item()
    return ToyResult(config, distances, step_s, contexts, data, samples)


def plot_toy_result(result: ToyResult, path: Path, num_contexts: int = 3) -> None:
    """PNG grid: one row per evaluation context, the exact data then each sampling mode."""
    plt = pyplot()
    method = result.config.method

    def label(name: str) -> str:  # the student's one-step jump, named after the objective that trained it
        return f"{method} 1-NFE" if name == "snapflow-1" and method != "snapflow" else name

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
    atomic_write(path, lambda temporary: figure.savefig(temporary, dpi=110, format="png"))
    plt.close(figure)


__all__ = ["ConditionalGaussianMixture", "ToyConfig", "ToyResult", "run_toy_experiment", "plot_toy_result"]
