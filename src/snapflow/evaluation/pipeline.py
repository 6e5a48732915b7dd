"""Evaluate checkpoints, built-in or LeRobot policy folders: closed-loop success per task, offline action error on
held-out demonstrations, and batch-1 latency, per (label, policy, sampling mode), into one
:class:`EvaluationReport`."""

from __future__ import annotations

import hashlib
import re
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import torch

from snapflow.benchmark.latency import LatencyRow, add_speedups, measure_latency
from snapflow.data.chunks import ChunkData
from snapflow.data.demonstrations import Demonstrations
from snapflow.envs.base import Benchmark
from snapflow.envs.factory import DEFAULT_BENCHMARK
from snapflow.errors import InvalidInputError
from snapflow.evaluation.closed_loop import ClosedLoopEvaluator, check_rtc
from snapflow.evaluation.config import N_ACT, OFFLINE_SAMPLES
from snapflow.evaluation.episode_log import EpisodeLog
from snapflow.evaluation.offline import offline_metrics
from snapflow.evaluation.path_modes import path_modes_by_task
from snapflow.evaluation.results import EvaluationReport, EvaluationRow, success_by_task
from snapflow.evaluation.switches import mean_smoothness
from snapflow.flow.modes import SamplingMode
from snapflow.flow.realtime import RealTimeChunking
from snapflow.policies.loaded import OpenedPolicy
from snapflow.reporting.files import recorded_path

Run = tuple[str, OpenedPolicy, SamplingMode]  # (label, policy, sampling mode)


def trained_benchmark(policy: OpenedPolicy) -> str:
    """The benchmark the policy's demonstrations came from (the default one where its training did not record it):
    where it is evaluated unless told otherwise."""
    return policy.training_data.get("env", DEFAULT_BENCHMARK)


def labelled_runs(policies: Mapping[str, tuple[OpenedPolicy, Sequence[SamplingMode]]]) -> list[Run]:
    """One run per (policy, mode) of ``policies`` (path -> its policy and modes), labelled by the mode alone for one
    policy, else by the last parts of the policy's path that tell it from the others, then the mode."""
    names = _distinct_names(list(policies))
    return [
        (mode.name if len(policies) == 1 else f"{names[path]} {mode.name}", policy, mode)
        for path, (policy, modes) in policies.items()
        for mode in modes
    ]


def runs_evaluator(
    runs: list[Run],
    benchmark: Benchmark,
    tasks: list[str],
    episodes_per_task: int,
    first_variation: int = 0,
    max_episode_steps: int | None = None,
) -> ClosedLoopEvaluator:
    """The closed-loop evaluator of ``runs``: frames of the first policy's size, from the cameras any of them reads,
    on each task's evaluation variations from ``first_variation`` on, each episode cut at ``max_episode_steps`` where
    given."""
    cameras = dict.fromkeys(name for _, loaded, _ in runs for name in loaded.processor.extra_cameras)
    return ClosedLoopEvaluator(
        benchmark,
        tasks,
        episodes_per_task,
        runs[0][1].processor.image_size,
        extra_cameras=tuple(cameras),
        first_variation=first_variation,
        max_episode_steps=max_episode_steps,
    )


def _distinct_names(paths: list[str]) -> dict[str, str]:
    """Each path's last parts, as few as tell it from the others (runs/teacher/lerobot_policy and
    runs/student/lerobot_policy: teacher/lerobot_policy, student/lerobot_policy)."""
    parts = {path: Path(path).resolve().parts for path in paths}
    for depth in range(1, max(len(each) for each in parts.values()) + 1):
        names = {path: "/".join(each[-depth:]) for path, each in parts.items()}
        if len(set(names.values())) == len(names):
            return names
    return {path: str(path) for path in paths}  # the same folder twice


def evaluate(
    runs: list[Run],
    benchmark: Benchmark,
    tasks: list[str],
    episodes_per_task: int,
    n_act: int = N_ACT,
    data: str | Path | None = None,
    offline_samples: int = OFFLINE_SAMPLES,
    seed: int = 0,
    progress: bool = True,
    timing: bool = True,
    episode_logs: str | Path | None = None,
    resume: bool = False,
    first_variation: int = 0,
    val_fraction: float | None = None,
    max_episode_steps: int | None = None,
    kept_logs: str | Path | None = None,
    rtc: RealTimeChunking | None = None,
    data_held_out: bool = False,
) -> EvaluationReport:
    """Closed-loop success, offline metrics (when ``data`` is given) and, with ``timing``, batch-1 latency for each
    (label, policy, mode); latency speedups are relative to the first entry. A jump mode (``snapflow-N``) on a
    policy never distilled is refused before anything runs. With ``episode_logs``, each run's finished waves of
    episodes are appended to a file there as they end (:class:`EpisodeLog`); with ``resume`` too, the waves already
    logged by the same evaluation are read back, not run again. Each task's episodes start from its evaluation
    variations ``first_variation`` on (LIBERO's fixed initial states). The offline metrics read the share of each
    task's episodes a policy's training held out, or ``val_fraction`` where given (a trainer that records none).
    ``max_episode_steps`` ends every episode there, short of the benchmark's own limit (a quick check). With
    ``kept_logs``, a whole copy of each episode log is kept there after each wave (a sweep's committed progress).
    With ``data_held_out``, ``data`` holds only held-out episodes (a video sweep's, their frames decoded): every one
    is scored.
    With ``rtc``, every run's chunks are planned under an inference delay and continue each other
    (:meth:`ClosedLoopEvaluator.run`), each run checked before any runs, and each row holds how smoothly its
    episodes' chunks joined (the action jump and jerk at the switches, :mod:`snapflow.evaluation.switches`)."""
    for _, loaded, mode in runs:
        loaded.check_mode(mode)
        if rtc is not None:
            _check_rtc_run(rtc, loaded, mode, n_act)
    evaluator = runs_evaluator(runs, benchmark, tasks, episodes_per_task, first_variation, max_episode_steps)
    demonstrations = Demonstrations.load(data) if data is not None else None
    held_out: dict[Path, ChunkData | None] = {}  # per checkpoint: its modes share one set of held-out chunks
    digests: dict[Path, str] = {}  # per checkpoint: its modes' logs share one digest of its weights
    report = EvaluationReport(
        benchmark.name,
        list(tasks),
        episodes_per_task,
        n_act,
        {},
        first_variation=first_variation,
        max_episode_steps=max_episode_steps,
        rtc=None if rtc is None else rtc.to_dict(),
    )
    # what every run's episodes depend on beside its own policy and mode
    settings = {"episodes_per_task": episodes_per_task, "n_act": n_act, "seed": seed}
    settings |= {"first_variation": first_variation, "max_episode_steps": max_episode_steps, "rtc": rtc}
    try:
        for index, (label, loaded, mode) in enumerate(runs):
            log = None
            if episode_logs is not None:
                if loaded.path not in digests:
                    digests[loaded.path] = weights_digest(loaded.policy)
                identity = _log_identity(label, loaded, digests[loaded.path], mode, tasks, evaluator, settings)
                name = _log_name(index, label)
                kept = None if kept_logs is None else Path(kept_logs) / name
                log = EpisodeLog(Path(episode_logs) / name, identity, resume, kept)
            earlier = sum(wave.seconds for wave in log.finished) if log is not None else 0.0
            started = time.perf_counter()
            episodes = evaluator.run(
                loaded.policy, loaded.processor, mode, n_act, seed, progress, log=log, rtc=rtc, switches=rtc is not None
            )
            row = EvaluationRow(
                recorded_path(loaded.path),
                mode.name,
                mode.num_steps,
                success_by_task(episodes),
                earlier + time.perf_counter() - started,
                path_modes=path_modes_by_task(episodes, len(benchmark.path_modes)),
                # a log written before switches were measured holds none for its waves: the row has none either
                switches=(
                    mean_smoothness([episode.switches for episode in episodes])
                    if rtc is not None and all(episode.switches is not None for episode in episodes)
                    else None
                ),
            )
            if demonstrations is not None:
                if loaded.path not in held_out:
                    fraction = loaded.held_out_share(val_fraction)
                    held_out[loaded.path] = _held_out_chunks(demonstrations, data_held_out, fraction, loaded)
                if held_out[loaded.path] is not None:
                    row.offline = offline_metrics(loaded.policy, held_out[loaded.path], mode, offline_samples, seed)
            report.rows[label] = row
    finally:
        evaluator.close()
    if timing:
        report.latency = checkpoint_latency(runs)
    return report


def _log_identity(
    label: str,
    loaded: OpenedPolicy,
    weights: str,
    mode: SamplingMode,
    tasks: list[str],
    evaluator: ClosedLoopEvaluator,
    settings: dict[str, Any],
) -> dict[str, Any]:
    """What a run's episodes depend on: its log is resumed only by the same run. ``settings``: the evaluation's
    episodes a task, n_act, seed, first variation, step limit and real-time chunking."""
    first, cut, rtc = settings["first_variation"], settings["max_episode_steps"], settings["rtc"]
    return {
        "label": label,
        "policy": recorded_path(loaded.path),  # as given where relative: a kept log is committed
        "weights": weights,
        "mode": mode.name,
        "tasks": tasks,
        "episodes_per_task": settings["episodes_per_task"],
        "envs_per_task": evaluator.envs_per_task,
        # only where the tasks run in groups (more of them than environments at once): the waves' order
        **({"task_groups": len(evaluator.task_groups)} if len(evaluator.task_groups) > 1 else {}),
        "n_act": settings["n_act"],
        "seed": settings["seed"],
        # only where set: a log written before the option existed is one of the first variations
        **({"first_variation": first} if first else {}),
        **({"max_episode_steps": cut} if cut else {}),
        **({"rtc": rtc.for_mode(mode).to_dict()} if rtc is not None else {}),
    }


def _held_out_chunks(
    demonstrations: Demonstrations, all_held_out: bool, val_fraction: float, loaded: OpenedPolicy
) -> ChunkData | None:
    """The chunks a policy's offline metrics score: every episode where ``demonstrations`` are held-out ones alone,
    else the share ``val_fraction`` of each task's episodes its training held out (None where that is none)."""
    if all_held_out:
        episodes = list(range(len(demonstrations.episodes)))
    else:
        _, episodes = demonstrations.split(val_fraction)
    return ChunkData(demonstrations, episodes, loaded.processor) if episodes else None


def _check_rtc_run(rtc: RealTimeChunking, loaded: OpenedPolicy, mode: SamplingMode, n_act: int) -> None:
    """Refuse a run the evaluator cannot do under ``rtc``, or a delay past the prefixes a policy was trained for."""
    resolved = check_rtc(rtc, loaded.policy, mode, n_act, loaded.processor.chunk_length)
    if resolved.kind == "trained" and rtc.delay > loaded.known_prefix_delay:
        raise InvalidInputError(
            f"{loaded.path} was distilled to be given at most {loaded.known_prefix_delay} actions of a previous chunk "
            f"(rtc_max_delay), so real-time chunking 'trained' cannot run it under an inference delay of {rtc.delay}: "
            "distil it with --rtc-max-delay at least that, or use --rtc inpaint"
        )


def _log_name(index: int, label: str) -> str:
    """The episode log's file name of the ``index``-th run: its label made safe for a file name."""
    return f"{index:02d}-{re.sub(r'[^A-Za-z0-9._-]+', '_', label)}.jsonl"


def weights_digest(policy: torch.nn.Module) -> str:
    """A digest of each tensor of ``policy``'s state by name and sum: what an episode log's identity names its
    weights by, so that a log is resumed only by the same policy (cheap beside an evaluation, even for a VLA)."""
    digest = hashlib.sha256()
    with torch.no_grad():
        for name, tensor in policy.state_dict().items():
            digest.update(f"{name}:{tensor.double().sum().item():.17g};".encode())
    return digest.hexdigest()


def checkpoint_latency(runs: list[Run], warmup: int = 10, repeats: int = 50) -> dict[str, LatencyRow]:
    """Batch-1 timing of each (label, policy, mode), each row with its own policy's prefix; speedups over the first."""
    rows: dict[str, LatencyRow] = {}
    for label, loaded, mode in runs:
        subject = loaded.bench_subject(label)
        measured = measure_latency(subject.policy, subject.observation, subject.noise, [mode], warmup, repeats)
        rows[label] = measured.modes[mode.name]
        rows[label].prefix = measured.prefix
    return add_speedups(rows)


__all__ = ["Run", "evaluate", "checkpoint_latency", "labelled_runs", "runs_evaluator", "trained_benchmark"]
