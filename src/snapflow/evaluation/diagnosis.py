"""Where a one-step policy fails on a task and what its chunk gets wrong there.

Each (label, policy, mode) rolls out the task's evaluation episodes closed-loop (the evaluator's one batched loop),
and every visited state is scored against the benchmark's scripted expert: how far the executed action is from the
expert's action at that state, by phase of the episode. The *failing phase* is where the last row (the one-step
student) strays from the expert in the episodes it fails furthest beyond what the first row (the teacher) does there. At the states of those moments every row predicts
its chunk for the same noise draws, beside the nearest demonstration's chunk (same task, nearest state): the figures
show whether the one-step chunk is biased (its draws agree with each other but not with the demonstration), averages
two ways of acting into one, or is as spread as the teacher's.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch

from snapflow.data.chunks import chunk_rows
from snapflow.data.demonstrations import Demonstrations
from snapflow.envs.base import Benchmark, Expert, Observation
from snapflow.envs.factory import make_benchmark
from snapflow.errors import InvalidInputError
from snapflow.evaluation.closed_loop import ClosedLoopEvaluator
from snapflow.evaluation.pipeline import Run, runs_evaluator, trained_benchmark
from snapflow.flow.modes import NAIVE_1, SNAPFLOW_1, SamplingMode
from snapflow.flow.solver import sample_actions
from snapflow.policies.checkpoint import LoadedPolicy
from snapflow.policies.loaded import OpenedPolicy

PHASE_STEPS = 25  # width of an episode phase, in environment steps


@dataclass
class RowTrace:
    """One row's closed-loop episodes on the task, scored against the expert."""

    label: str
    mode: str
    successes: int
    episodes: int
    # mean |executed action - expert action| (Euclidean, raw action units) per phase of PHASE_STEPS steps
    deviation_failed: list[float | None]
    deviation_succeeded: list[float | None]
    deviation_all: list[float | None]
    mean_deviation: float


@dataclass
class ChunkComparison:
    """Every row's chunks at one state of a failed student episode, beside the nearest demonstration's chunk."""

    variation: int
    step: int
    state: list[float]
    demonstration_distance: float  # between the state and the nearest demonstration state (raw units)
    expert_action: list[float]
    demonstration_chunk: list[list[float]]
    # per row label: its draws (draws x chunk x action); the mean squared error of the draws to the demonstration's
    # chunk; their mean standard deviation across draws; the mean distance of their first actions to the expert's
    chunks: dict[str, list[list[list[float]]]] = field(default_factory=dict)
    error_to_demonstration: dict[str, float] = field(default_factory=dict)
    spread: dict[str, float] = field(default_factory=dict)
    first_action_to_expert: dict[str, float] = field(default_factory=dict)


@dataclass
class Diagnosis:
    benchmark: str
    task: str
    episodes: int
    n_act: int
    phase_steps: int
    rows: list[RowTrace]
    # the phase where the last row's failed episodes stray from the expert furthest beyond the first row's episodes
    failing_phase: int | None
    comparisons: list[ChunkComparison] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def _phase_means(deviations: list[np.ndarray], phases: int) -> list[float | None]:
    means = []
    for phase in range(phases):
        parts = [d[phase * PHASE_STEPS : (phase + 1) * PHASE_STEPS] for d in deviations]
        values = np.concatenate([p for p in parts if len(p)]) if any(len(p) for p in parts) else np.empty(0)
        means.append(float(values.mean()) if len(values) else None)
    return means


def _nearest_chunk(demonstrations: Demonstrations, task: str, state: np.ndarray, length: int):
    """The chunk that follows the demonstration state of ``task`` nearest to ``state``, and the distance."""
    rows = demonstrations.rows([i for i, e in enumerate(demonstrations.episodes) if e.task == task])
    distances = np.linalg.norm(demonstrations.states[rows] - state, axis=1)
    best = rows[int(distances.argmin())]
    return demonstrations.actions[chunk_rows(demonstrations, np.array([best]), length)[0]], float(distances.min())


@dataclass
class _EpisodeTraces:
    """One run's closed-loop episodes of the task, scored against the expert: per episode (the evaluator's slot), the
    visited observations, the expert's action at each, the distance of the executed action to it, and success."""

    visited: list[list[Observation]]
    expert_actions: list[np.ndarray]
    deviations: list[np.ndarray]
    success: list[bool]

    @property
    def failed(self) -> list[int]:
        return [slot for slot, ok in enumerate(self.success) if not ok]


def _trace(
    evaluator: ClosedLoopEvaluator,
    expert: Expert,
    loaded: LoadedPolicy,
    mode: SamplingMode,
    n_act: int,
    seed: int,
    progress: bool,
    episodes: int,
) -> _EpisodeTraces:
    """The evaluator's episodes with every (observation, executed action) of each, scored against ``expert``."""
    visited: list[list[Observation]] = [[] for _ in range(episodes)]
    executed: list[list[np.ndarray]] = [[] for _ in range(episodes)]

    def record(slot: int, observation: Observation, action: np.ndarray) -> None:
        visited[slot].append(observation)
        executed[slot].append(np.asarray(action, dtype=np.float64))

    results = evaluator.run(loaded.policy, loaded.processor, mode, n_act, seed, progress, record=record)
    wanted, deviations = [], []
    for observations, actions in zip(visited, executed, strict=True):
        expert.reset(observations[0])  # then fed the visited states in order, as it would be driving
        wanted.append(np.stack([expert.act(observation) for observation in observations]))
        deviations.append(np.linalg.norm(np.stack(actions) - wanted[-1], axis=1))
    return _EpisodeTraces(visited, wanted, deviations, [result.success for result in results])


def _summarise(label: str, mode: SamplingMode, traces: _EpisodeTraces) -> RowTrace:
    """A run's success and its distance to the expert by phase (failed, successful and all episodes)."""
    deviations, success = traces.deviations, traces.success
    phases = -(-max(len(d) for d in deviations) // PHASE_STEPS)
    return RowTrace(
        label,
        mode.name,
        sum(success),
        len(success),
        _phase_means([d for d, ok in zip(deviations, success, strict=True) if not ok], phases),
        _phase_means([d for d, ok in zip(deviations, success, strict=True) if ok], phases),
        _phase_means(deviations, phases),
        float(np.concatenate(deviations).mean()),
    )


def _failing_phase(reference: RowTrace, student: RowTrace) -> int:
    """The phase where the student's failed episodes stray from the expert most beyond what the reference (the
    teacher) does there."""
    baseline = reference.deviation_all
    excess = [
        (value - (baseline[phase] if phase < len(baseline) and baseline[phase] is not None else 0.0), phase)
        for phase, value in enumerate(student.deviation_failed)
        if value is not None
    ]
    return max(excess)[1]


def _failed_moments(traces: _EpisodeTraces, phase: int, states: int, n_act: int) -> list[tuple[int, int]]:
    """(slot, step) of up to ``states`` failed episodes at the re-planning moment (every ``n_act``-th step, where a
    chunk was sampled and the cameras rendered) where each strays furthest within ``phase``, furthest first."""
    moments = []
    for slot in traces.failed:
        deviations = traces.deviations[slot]
        steps = np.arange(phase * PHASE_STEPS, min((phase + 1) * PHASE_STEPS, len(deviations)))
        steps = steps[steps % n_act == 0]
        if len(steps):
            step = int(steps[deviations[steps].argmax()])
            moments.append((float(deviations[step]), slot, step))
    return [(slot, step) for _, slot, step in sorted(moments, reverse=True)[:states]]


def _compare_chunks(
    runs: list[Run],
    observation: Observation,
    expert_action: np.ndarray,
    slot: int,
    step: int,
    demonstrations: Demonstrations,
    task: str,
    draws: int,
    generator: torch.Generator,
) -> ChunkComparison:
    """Every run's ``draws`` chunks at ``observation`` for the same noise, beside the nearest demonstration's."""
    processor = runs[0][1].processor
    reference, distance = _nearest_chunk(demonstrations, task, observation.state, processor.chunk_length)
    noise = torch.randn(draws, processor.chunk_length, processor.action_dim, generator=generator)
    comparison = ChunkComparison(
        slot,  # the evaluator's slots of one task are its evaluation variations in order
        step,
        observation.state.tolist(),
        distance,
        expert_action.tolist(),
        reference.tolist(),
    )
    for label, loaded, mode in runs:
        batch = loaded.processor.observation(
            np.repeat(observation.state[None], draws, 0),
            [observation.instruction] * draws,
            np.repeat(observation.image[None], draws, 0) if loaded.processor.image_size else None,
            {
                name: np.repeat(observation.extra_images[name][None], draws, 0)
                for name in loaded.processor.extra_cameras
            },
        )
        chunks = loaded.processor.unnormalize_actions(sample_actions(loaded.policy, batch, noise, mode)).numpy()
        comparison.chunks[label] = chunks.tolist()
        comparison.error_to_demonstration[label] = float(((chunks - reference[None]) ** 2).mean())
        comparison.spread[label] = float(chunks.std(0).mean())
        comparison.first_action_to_expert[label] = float(np.linalg.norm(chunks[:, 0] - expert_action, axis=1).mean())
    return comparison


def diagnose_student(
    teacher: OpenedPolicy,
    student: OpenedPolicy,
    task: str,
    episodes: int,
    n_act: int,
    teacher_steps: int = 10,
    env: str | None = None,
    data: str | Path | None = None,
    seed: int = 0,
    progress: bool = True,
) -> Diagnosis:
    """:func:`diagnose_task` of the student's one jump against its teacher at ``teacher_steps`` Euler steps and at its
    naive one step, on ``env`` (default: the benchmark the student was distilled on) with the demonstrations ``data``
    (default: those it was distilled on)."""
    benchmark = make_benchmark(env or trained_benchmark(student))
    (task,) = benchmark.check_tasks([task])
    data = data or student.training_data.get("path")
    if data is None:
        raise InvalidInputError(f"{student.path} does not name its demonstrations; pass --data")
    runs = [
        (f"teacher {teacher_steps}-NFE", teacher, SamplingMode.parse(f"teacher-{teacher_steps}")),
        ("naive 1-NFE", teacher, NAIVE_1),
        ("SnapFlow 1-NFE", student, SNAPFLOW_1),
    ]
    return diagnose_task(
        runs, benchmark, task, episodes, Demonstrations.load(data), n_act, seed=seed, progress=progress
    )


@torch.no_grad()
def diagnose_task(
    runs: list[Run],
    benchmark: Benchmark,
    task: str,
    episodes: int,
    demonstrations: Demonstrations,
    n_act: int,
    seed: int = 0,
    draws: int = 8,
    states: int = 3,
    progress: bool = True,
) -> Diagnosis:
    """Trace every run on ``task``'s first ``episodes`` evaluation variations against the expert, find the failing
    phase of the last run, and compare every run's chunks at up to ``states`` of its failed moments."""
    for _, loaded, mode in runs:
        loaded.check_mode(mode)
    evaluator = runs_evaluator(runs, benchmark, [task], episodes)
    expert = benchmark.make_expert(task)
    try:
        traces = [_trace(evaluator, expert, loaded, mode, n_act, seed, progress, episodes) for _, loaded, mode in runs]
    finally:
        evaluator.close()
    rows = [_summarise(label, mode, trace) for (label, _, mode), trace in zip(runs, traces, strict=True)]
    diagnosis = Diagnosis(benchmark.name, task, episodes, n_act, PHASE_STEPS, rows, None)
    student = traces[-1]
    if not student.failed:
        return diagnosis
    diagnosis.failing_phase = _failing_phase(rows[0], rows[-1])
    generator = torch.Generator().manual_seed(seed)
    for slot, step in _failed_moments(student, diagnosis.failing_phase, states, n_act):
        observation, expert_action = student.visited[slot][step], student.expert_actions[slot][step]
        diagnosis.comparisons.append(
            _compare_chunks(runs, observation, expert_action, slot, step, demonstrations, task, draws, generator)
        )
    return diagnosis


__all__ = ["ChunkComparison", "Diagnosis", "RowTrace", "diagnose_student", "diagnose_task"]
