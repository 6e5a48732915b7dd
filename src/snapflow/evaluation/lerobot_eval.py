"""LeRobot's own ``lerobot-eval`` on LIBERO, one task at a time, read back as snapflow's :class:`EvaluationRow`: the
figure a LeRobot user gets, beside snapflow's evaluator's on the same initial states.

Each task runs as a subprocess of this interpreter's environment, ``python -m snapflow.adapters.lerobot.libero``
(``lerobot-eval`` itself, every argument LeRobot's, with the package's reader of LIBERO's initial states), in one
batch of environments: LeRobot's environment k starts from the task's initial state k. Only the first batch is tied
to the first states (LeRobot's vector environment resets a finished episode by itself, which moves that environment
on to another state), so a task's episodes are one batch, at most :data:`MAX_EPISODES` (a LIBERO environment with
cameras holds about 850 MB). A finished task's ``eval_info.json`` is kept, so an interrupted evaluation goes on from
the next task."""

from __future__ import annotations

import json
import shutil
import sys
import time
from pathlib import Path
from typing import Any

from snapflow.adapters.lerobot_commands import LOG_TAIL_CHARACTERS, run_lerobot_command
from snapflow.adapters.lerobot_types import LEROBOT_POLICY_TYPES
from snapflow.envs.libero import suite_of
from snapflow.errors import InvalidInputError, SnapflowError
from snapflow.evaluation.results import EpisodeResult, EvaluationRow, success_by_task
from snapflow.flow.modes import SamplingMode
from snapflow.reporting.files import recorded_path, write_json

#: a task's episodes run as one batch of LeRobot environments, each from its own initial state
MAX_EPISODES = 10
EVAL_INFO = "eval_info.json"  # lerobot-eval's own results file, in its output folder
TIMING = "wall_time.json"  # beside it: the task's wall time, which lerobot-eval does not record


def mode_arguments(policy: Path, mode: SamplingMode) -> list[str]:
    """The flags that make ``lerobot-eval`` sample ``mode``: a student type's ``sampling_mode``, or a LeRobot
    teacher's number of Euler steps in its type's own field (a plain type knows no jump)."""
    from snapflow.adapters.lerobot.registry import adapter_class

    config = json.loads((policy / "config.json").read_text())
    if config["type"] in {declared.student_type for declared in LEROBOT_POLICY_TYPES.values()}:
        return [f"--policy.sampling_mode={mode.name}"]
    if mode.jump:
        raise InvalidInputError(
            f"{policy} is LeRobot's {config['type']!r}, which has no jump to sample {mode.name}: give a student type"
        )
    return [f"--policy.{adapter_class(config['type']).steps_field}={mode.num_steps}"]


def lerobot_eval_arguments(
    policy: Path,
    task: str,
    episodes: int,
    image_size: int,
    n_action_steps: int,
    mode: SamplingMode,
    output: Path,
    max_episode_steps: int | None = None,
) -> list[str]:
    """``lerobot-eval``'s flags for ``episodes`` of snapflow's LIBERO task ``task`` (e.g. ``libero_spatial_3``) in
    one batch, cameras rendered at ``image_size`` as the demonstrations were, ``n_action_steps`` of each chunk
    executed, on the CPU; each episode cut at ``max_episode_steps`` where given (LeRobot's ``env.episode_length``)."""
    if not 1 <= episodes <= MAX_EPISODES:
        raise InvalidInputError(
            f"lerobot-eval runs a task's episodes as one batch of environments from LIBERO's first initial states: "
            f"1 to {MAX_EPISODES} episodes a task, got {episodes}"
        )
    suite, index = suite_of(task)
    return [
        f"--policy.path={policy}",
        "--policy.device=cpu",
        f"--policy.n_action_steps={n_action_steps}",
        *mode_arguments(policy, mode),
        "--env.type=libero",
        f"--env.task={suite}",
        f"--env.task_ids=[{index}]",
        f"--env.observation_height={image_size}",
        f"--env.observation_width={image_size}",
        *([f"--env.episode_length={max_episode_steps}"] if max_episode_steps else []),
        f"--eval.n_episodes={episodes}",
        f"--eval.batch_size={episodes}",
        "--eval.use_async_envs=false",
        f"--output_dir={output}",
    ]


def _run_task(arguments: list[str], policy: Path, output: Path, threads: int | None) -> None:
    """One task's ``lerobot-eval``, its log beside its folder, run from inside the policy folder (where LeRobot finds
    a VLM kept there by the relative path its files name it by); a folder without results (an interrupted run) is
    cleared first, and the wall time written once the results are there."""
    if output.exists():
        shutil.rmtree(output)
    log = output.with_name(f"{output.name}.log")
    started = time.perf_counter()
    command = [sys.executable, "-m", "snapflow.adapters.lerobot.libero", *arguments]
    run_lerobot_command("lerobot-eval", command, log, threads, directory=policy)
    if not (output / EVAL_INFO).is_file():
        raise SnapflowError(
            f"lerobot-eval wrote no {EVAL_INFO}; its output is in {log}, ending:\n"
            f"{log.read_text()[-LOG_TAIL_CHARACTERS:]}"
        )
    write_json(output / TIMING, {"wall_time_s": time.perf_counter() - started})


def task_episodes(task: str, eval_info: dict[str, Any]) -> list[EpisodeResult]:
    """The episodes of ``task`` in a ``lerobot-eval`` results file (one task's): episode k from initial state k."""
    (entry,) = eval_info["per_task"]
    successes = entry["metrics"]["successes"]
    return [EpisodeResult(task, index, bool(success), 0) for index, success in enumerate(successes)]


def run_lerobot_eval(
    policy: str | Path,
    tasks: list[str],
    episodes: int,
    image_size: int,
    n_action_steps: int,
    mode: SamplingMode,
    output: str | Path,
    threads: int | None = None,
    kept: str | Path | None = None,
    max_episode_steps: int | None = None,
) -> EvaluationRow:
    """``episodes`` of each LIBERO task in ``tasks`` by LeRobot's ``lerobot-eval`` on the LeRobot policy folder
    ``policy`` sampling ``mode``, each task's run in ``output/<task>``, the tasks already there kept. ``kept``: a
    folder that gets a copy of each task's ``eval_info.json`` (to commit: the files are LeRobot's own). Episodes
    record no step counts (lerobot-eval writes none); ``closed_loop_s`` is the tasks' wall time. A task kept with its
    wall time is what :func:`restore_kept_tasks` puts back on another machine. ``max_episode_steps`` cuts each episode
    short of the suite's limit (a quick check)."""
    policy, output = Path(policy), Path(output)
    wall_time = 0.0
    results: list[EpisodeResult] = []
    for task in tasks:
        folder = output / task
        if not (folder / TIMING).is_file():
            # absolute: lerobot-eval runs from inside the policy folder
            arguments = lerobot_eval_arguments(
                policy.resolve(), task, episodes, image_size, n_action_steps, mode, folder.resolve(), max_episode_steps
            )
            _run_task(arguments, policy, folder, threads)
        eval_info = json.loads((folder / EVAL_INFO).read_text())
        if kept is not None:
            write_json(Path(kept) / task / EVAL_INFO, eval_info)
            shutil.copy2(folder / TIMING, Path(kept) / task / TIMING)
        results += task_episodes(task, eval_info)
        wall_time += json.loads((folder / TIMING).read_text())["wall_time_s"]
    return EvaluationRow(recorded_path(policy), mode.name, mode.num_steps, success_by_task(results), wall_time)


def finished_tasks(folder: str | Path) -> list[str]:
    """The tasks :func:`run_lerobot_eval` finished in ``folder`` (its output, or the folder it keeps them in)."""
    folder = Path(folder)
    tasks = sorted(folder.iterdir()) if folder.is_dir() else []
    return [task.name for task in tasks if (task / EVAL_INFO).is_file() and (task / TIMING).is_file()]


def restore_kept_tasks(kept: str | Path, output: str | Path) -> list[str]:
    """Put the tasks that :func:`run_lerobot_eval` finished and kept in ``kept`` (on another machine) into ``output``,
    where it reads them back instead of running them again; the tasks put back."""
    restored = finished_tasks(kept)
    for task in restored:
        shutil.copytree(Path(kept) / task, Path(output) / task, dirs_exist_ok=True)
    return restored


__all__ = [
    "MAX_EPISODES",
    "finished_tasks",
    "lerobot_eval_arguments",
    "mode_arguments",
    "restore_kept_tasks",
    "run_lerobot_eval",
    "task_episodes",
]
