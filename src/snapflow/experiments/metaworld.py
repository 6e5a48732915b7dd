"""The main job on Meta-World MT10: collect -> train the teacher -> SnapFlow-distill -> evaluate -> time.

Each stage is a function the CLI calls; ``run_demo`` chains them and writes one report.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import torch

from snapflow.data.collect import collect_demonstrations
from snapflow.data.demonstrations import META_FILE, Demonstrations
from snapflow.envs.metaworld import MT10_TASKS
from snapflow.evaluation.closed_loop import MetaWorldEvaluator, success_by_task
from snapflow.evaluation.offline import offline_metrics
from snapflow.evaluation.report import write_report
from snapflow.flow.solver import NAIVE_1, SNAPFLOW_1, TEACHER_10, SamplingMode
from snapflow.flow.time_sampling import UniformTimeSampler
from snapflow.nn.snapflow_policy import SnapFlowPolicy
from snapflow.benchmark.latency import add_speedups, measure_latency
from snapflow.objective.snapflow import SnapFlowObjective
from snapflow.policies.minivla import MiniVLA, MiniVLAConfig, MiniVLAProcessor
from snapflow.training.checkpoint import LoadedPolicy, load_policy, policy_metadata
from snapflow.training.data import ChunkData
from snapflow.training.distill import DistillSettings, TargetOption
from snapflow.training.trainer import TrainConfig, train


@dataclass(frozen=True)
class DemoPreset:
    """Everything the demo runs; ``fast`` is the README default, ``full`` the stronger, longer run."""

    tasks: tuple[str, ...] = MT10_TASKS
    episodes_per_task: int = 30
    val_fraction: float = 0.1
    policy: MiniVLAConfig = field(default_factory=MiniVLAConfig)
    # A converged teacher matters (the paper: distilling an under-trained one distills noise); the student
    # starts at the teacher's final learning rate (3e-5, near the paper's 2.5e-5) so it stays in its basin.
    teacher: TrainConfig = field(default_factory=lambda: TrainConfig(steps=5000, learning_rate=3e-4))
    student: TrainConfig = field(default_factory=lambda: TrainConfig(steps=2000, learning_rate=3e-5, warmup_steps=50))
    distill: DistillSettings = field(default_factory=DistillSettings)
    eval_episodes: int = 20
    n_act: int = 4


PRESETS: dict[str, DemoPreset] = {
    "fast": DemoPreset(),
    "full": DemoPreset(
        episodes_per_task=50,
        teacher=TrainConfig(steps=10000, learning_rate=3e-4),
        student=TrainConfig(steps=4000, learning_rate=3e-5, warmup_steps=100),
        eval_episodes=50,
    ),
}


def collect(
    tasks: list[str], episodes_per_task: int, output: str | Path, image_size: int | None = None, progress: bool = True,
    via_points: bool = False,
) -> Demonstrations:
    demonstrations = collect_demonstrations(tasks, episodes_per_task, image_size, progress, via_points)
    demonstrations.save(output)
    return demonstrations


def _chunk_data(demonstrations: Demonstrations, processor: MiniVLAProcessor, val_fraction: float) -> tuple[ChunkData, ChunkData | None]:
    train_episodes, val_episodes = demonstrations.split(val_fraction)
    return ChunkData(demonstrations, train_episodes, processor), ChunkData(demonstrations, val_episodes, processor) if val_episodes else None


def train_teacher(
    data: str | Path, output: str | Path, policy_config: MiniVLAConfig, config: TrainConfig,
    val_fraction: float = 0.1, resume: bool = False, progress: bool = True,
) -> dict[str, Any]:
    """Plain flow matching (alpha = 1) on the demonstrations; normalisation from the training episodes."""
    demonstrations = Demonstrations.load(data)
    train_episodes, _ = demonstrations.split(val_fraction)
    processor = MiniVLAProcessor(policy_config, demonstrations.stats(train_episodes, policy_config.state_dim))
    torch.manual_seed(config.seed)
    policy = SnapFlowPolicy(MiniVLA(policy_config), target_time=False)
    train_data, val_data = _chunk_data(demonstrations, processor, val_fraction)
    metadata = policy_metadata(policy, processor, stage="teacher", data={"path": str(data), "val_fraction": val_fraction})
    objective = SnapFlowObjective(alpha=1.0, time_sampler=UniformTimeSampler())
    return train(policy, objective, train_data, val_data, config, output, metadata, resume=resume, progress=progress)


def _expert_parameter_names(policy: SnapFlowPolicy) -> list[str]:
    """What distillation trains with the prefix frozen: the action expert and phi_s."""
    frozen = {id(p) for p in policy.model.prefix_parameters()}
    return [name for name, p in policy.named_parameters() if id(p) not in frozen]


def distill(
    teacher: str | Path, data: str | Path, output: str | Path, config: TrainConfig, settings: DistillSettings | None = None,
    val_fraction: float | None = None, resume: bool = False, progress: bool = True,
) -> dict[str, Any]:
    """SnapFlow (or a baseline, see ``DistillSettings``): the student starts as the teacher plus a zero-initialised
    phi_s; prefix frozen by default."""
    settings = settings or DistillSettings()
    loaded = load_policy(teacher, target_time=settings.target_time)
    demonstrations = Demonstrations.load(data)
    if val_fraction is None:
        val_fraction = loaded.val_fraction
    train_data, val_data = _chunk_data(demonstrations, loaded.processor, val_fraction)
    policy = loaded.policy
    trainable = None
    if settings.freeze_prefix:
        names = set(_expert_parameter_names(policy))
        trainable = [p for name, p in policy.named_parameters() if name in names]
    metadata = policy_metadata(policy, loaded.processor, stage="snapflow", teacher=str(loaded.path), distill=asdict(settings),
                               data={"path": str(data), "val_fraction": val_fraction})
    return train(policy, settings.objective(UniformTimeSampler()), train_data, val_data, config, output, metadata, resume=resume, trainable=trainable, progress=progress)


def training_cost(
    teacher: str | Path, data: str | Path, options: list[TargetOption], batch_size: int = 64, warmup: int = 5, repeats: int = 30,
) -> dict[str, Any]:
    """Seconds per distillation step of each SnapFlow target on the MiniVLA student of ``teacher``, on one batch of
    its demonstrations, as ``distill`` trains it (phi_s added, prefix frozen); see :mod:`snapflow.benchmark.training_cost`."""
    from snapflow.benchmark.training_cost import time_training_steps

    loaded = load_policy(teacher, target_time=True)
    train_data, _ = _chunk_data(Demonstrations.load(data), loaded.processor, loaded.val_fraction)
    observation, actions = train_data.batch(torch.randint(len(train_data), (batch_size,), generator=torch.Generator().manual_seed(0)))
    return time_training_steps(loaded.policy, observation, actions, options, UniformTimeSampler(), _expert_parameter_names(loaded.policy),
                               warmup, repeats)


def evaluate(
    runs: list[tuple[str, LoadedPolicy, SamplingMode]], tasks: list[str], episodes_per_task: int, n_act: int,
    data: str | Path | None = None, offline_samples: int = 500, seed: int = 0, progress: bool = True, via_points: bool = False,
    timing: bool = True,
) -> dict[str, Any]:
    """Closed-loop success, offline metrics (when ``data`` is given) and, with ``timing``, batch-1 latency for
    each (label, policy, mode); latency speedups are relative to the first entry. ``via_points``: the
    multimodal variant's success criterion (see :mod:`snapflow.envs.via_points`)."""
    first = runs[0][1].processor.config
    evaluator = MetaWorldEvaluator(tasks, episodes_per_task, first.image_size if first.use_image else None, via_points)
    demonstrations = Demonstrations.load(data) if data is not None else None
    held_out: dict[Path, ChunkData | None] = {}  # per checkpoint: its modes share one set of held-out chunks
    report: dict[str, Any] = {"tasks": tasks, "episodes_per_task": episodes_per_task, "n_act": n_act, "via_points": via_points, "rows": {}}
    try:
        for label, loaded, mode in runs:
            started = time.perf_counter()
            episodes = evaluator.run(loaded.policy, loaded.processor, mode, n_act, seed, progress)
            row: dict[str, Any] = {"policy": str(loaded.path), "mode": mode.name, "nfe": mode.num_steps,
                                   "success": success_by_task(episodes), "closed_loop_s": time.perf_counter() - started}
            if demonstrations is not None:
                if loaded.path not in held_out:
                    _, val_episodes = demonstrations.split(loaded.val_fraction)
                    held_out[loaded.path] = ChunkData(demonstrations, val_episodes, loaded.processor) if val_episodes else None
                if held_out[loaded.path] is not None:
                    row["offline"] = offline_metrics(loaded.policy, held_out[loaded.path], mode, offline_samples, seed)
            report["rows"][label] = row
    finally:
        evaluator.close()
    if timing:
        report["latency"] = latency(runs)
    return report


def latency(runs: list[tuple[str, LoadedPolicy, SamplingMode]], warmup: int = 10, repeats: int = 50) -> dict[str, Any]:
    """Batch-1 timing of each (label, policy, mode) on one observation from the first task."""
    results: dict[str, Any] = {}
    for label, loaded, mode in runs:
        config = loaded.processor.config
        torch.manual_seed(0)
        state = torch.zeros(1, config.state_dim).numpy()
        images = torch.zeros(1, config.image_size, config.image_size, 3, dtype=torch.uint8).numpy() if config.use_image else None
        observation = loaded.processor.observation(state, ["push the puck to the goal"], images)
        noise = torch.randn(1, config.chunk_length, config.action_dim)
        measured = measure_latency(loaded.policy.eval(), observation, noise, [mode], warmup, repeats)
        results[label] = {"prefix": measured["prefix"], **measured["modes"][mode.name]}
    return add_speedups(results)


def run_demo(preset: DemoPreset, output: str | Path, progress: bool = True, resume: bool = False) -> dict[str, Any]:
    """collect -> train -> distill -> evaluate; writes ``report.json``, ``report.md`` and PNG plots."""
    output = Path(output)
    timings: dict[str, float] = {}
    started = time.perf_counter()
    data, teacher_dir, student_dir = output / "data", output / "teacher", output / "snapflow"
    if not (resume and (data / META_FILE).is_file()):
        collect(list(preset.tasks), preset.episodes_per_task, data, progress=progress)
    timings["collect_s"] = time.perf_counter() - started
    train_teacher(data, teacher_dir, preset.policy, preset.teacher, preset.val_fraction, resume=resume, progress=progress)
    timings["teacher_s"] = time.perf_counter() - started - sum(timings.values())
    distill(teacher_dir, data, student_dir, preset.student, preset.distill, preset.val_fraction, resume=resume, progress=progress)
    timings["distill_s"] = time.perf_counter() - started - sum(timings.values())
    teacher, student = load_policy(teacher_dir), load_policy(student_dir)
    runs = [("teacher 10-NFE", teacher, TEACHER_10), ("naive 1-NFE", teacher, NAIVE_1), ("SnapFlow 1-NFE", student, SNAPFLOW_1)]
    report = evaluate(runs, list(preset.tasks), preset.eval_episodes, preset.n_act, data, progress=progress)
    timings["evaluate_s"] = time.perf_counter() - started - sum(timings.values())
    timings["total_s"] = time.perf_counter() - started
    report["timings"] = timings
    report["preset"] = {**asdict(replace(preset, policy=None)), "policy": preset.policy.to_dict()}
    write_report(report, output)
    return report


__all__ = ["DemoPreset", "PRESETS", "collect", "train_teacher", "distill", "evaluate", "latency", "run_demo"]
