"""Closed-loop success on a benchmark: the episodes of all tasks run side by side, one batched policy call for every
environment that needs a new chunk, so inference uses every core while environments step. At most ``max_envs``
environments exist (by default the benchmark's :attr:`~snapflow.envs.base.Benchmark.max_envs`), made once and reset
to each variation in turn: a Meta-World environment holds ~21 MB, 500 episodes side by side took 10.5 GB, and
environments made anew for each wave did not hand their memory back."""

from __future__ import annotations

import time
from collections import deque
from collections.abc import Callable, Sequence

import numpy as np
import torch
from tqdm.auto import tqdm

from snapflow.envs.base import Benchmark, Environment, Observation
from snapflow.errors import InvalidInputError
from snapflow.evaluation.episode_log import EpisodeLog, FinishedWave
from snapflow.evaluation.results import EpisodeResult
from snapflow.flow.modes import SamplingMode
from snapflow.flow.solver import sample_actions
from snapflow.policies.processor import Processor
from snapflow.protocol import FlowPolicy


class ClosedLoopEvaluator:
    """Runs every (task, episode) slot of the benchmark's evaluation split, for one policy and mode per ``run``.

    A task's episodes start from its evaluation variations ``first_variation`` on (LIBERO's fixed initial states, in
    order). Each task gets ``max_envs // len(tasks)`` environments (at least one), made at the first run and kept for the
    next ones: episodes run in waves of that many variations per task, every task side by side, the noise drawn
    from one generator across waves. Results depend on ``max_envs`` only when a task has more episodes than that.
    The environments render ``image_size`` frames from the benchmark's main camera and ``extra_cameras`` alone: the
    cameras the evaluated policies read, no more. ``max_episode_steps`` ends each episode there, short of the
    environment's own limit (a quick check of a chain, not a success rate to report).
    """

    def __init__(
        self,
        benchmark: Benchmark,
        tasks: list[str],
        episodes_per_task: int,
        image_size: int | None = None,
        max_envs: int | None = None,
        extra_cameras: Sequence[str] = (),
        first_variation: int = 0,
        max_episode_steps: int | None = None,
    ) -> None:
        benchmark.check_tasks(tasks)
        self.extra_cameras = benchmark.check_cameras(extra_cameras)
        benchmark.check_episodes("eval", episodes_per_task, first_variation)
        max_envs = benchmark.max_envs if max_envs is None else max_envs
        if max_envs < 1:
            raise InvalidInputError(f"max_envs must be at least 1, got {max_envs}")
        if max_episode_steps is not None and max_episode_steps < 1:
            raise InvalidInputError(f"max_episode_steps must be at least 1, got {max_episode_steps}")
        self.benchmark, self.tasks, self.image_size = benchmark, tasks, image_size
        self.max_episode_steps = max_episode_steps
        # the variations from first_variation on (LIBERO: its fixed initial states), the first ones unless told
        variations = range(first_variation, first_variation + episodes_per_task)
        self.slots = [(task, variation) for task in tasks for variation in variations]
        self.envs_per_task = min(episodes_per_task, max(1, max_envs // len(tasks)))
        # wave -> (slot, environment index) pairs, task-major as the slots: one wave is the old all-at-once loop
        self.waves = [
            [
                (t * episodes_per_task + v, t * self.envs_per_task + v - first)
                for t in range(len(tasks))
                for v in range(first, min(first + self.envs_per_task, episodes_per_task))
            ]
            for first in range(0, episodes_per_task, self.envs_per_task)
        ]
        self._envs: list[Environment] = []

    def _environments(self) -> list[Environment]:
        if not self._envs:
            self._envs = [
                self.benchmark.make_env(task, "eval", self.image_size, self.extra_cameras)
                for task in self.tasks
                for _ in range(self.envs_per_task)
            ]
        return self._envs

    @torch.no_grad()
    def run(
        self,
        policy: FlowPolicy,
        processor: Processor,
        mode: SamplingMode,
        n_act: int,
        seed: int = 0,
        progress: bool = True,
        record: Callable[[int, Observation, np.ndarray], None] | None = None,
        log: EpisodeLog | None = None,
    ) -> list[EpisodeResult]:
        """Roll out every slot to success or the step limit, re-planning a chunk every ``n_act`` actions;
        ``record(slot, observation, action)`` is called before each step (to trace episodes). With ``log``, each
        finished wave is appended to it, and the waves it already holds are taken from it, not run again (nor
        recorded): the run goes on from the noise generator's state after the last of them."""
        if not 1 <= n_act <= processor.chunk_length:
            raise InvalidInputError(
                f"n_act must be in [1, {processor.chunk_length}] (the policy's chunk length), got {n_act}"
            )
        unrendered = [name for name in processor.extra_cameras if name not in self.extra_cameras]
        if unrendered:
            raise InvalidInputError(f"the policy reads camera(s) {unrendered} that this evaluator does not render")
        policy.eval()
        generator = torch.Generator().manual_seed(seed)
        results: dict[int, EpisodeResult] = {}
        logged = log.finished if log is not None else []
        with tqdm(total=len(self.slots), desc=f"closed loop {mode.name}", disable=not progress, leave=False) as bar:
            for index, wave in enumerate(self.waves):
                slots = [slot for slot, _ in wave]
                if index < len(logged):
                    finished = logged[index].episodes
                    generator.set_state(logged[index].generator_state)
                    bar.update(len(finished))
                else:
                    started = time.perf_counter()
                    envs = self._environments()  # made at the first wave that runs: none for a finished log
                    finished = self._run_wave(
                        [envs[env] for _, env in wave],
                        slots,
                        policy,
                        processor,
                        mode,
                        n_act,
                        generator,
                        bar.update,
                        record,
                    )
                    if log is not None:
                        log.append(FinishedWave(finished, time.perf_counter() - started, generator.get_state()))
                results.update(zip(slots, finished, strict=True))
        return [results[slot] for slot in range(len(self.slots))]

    def _run_wave(
        self,
        envs: list[Environment],
        slots: list[int],
        policy: FlowPolicy,
        processor: Processor,
        mode: SamplingMode,
        n_act: int,
        generator: torch.Generator,
        finished: Callable[[], object],
        record: Callable[[int, Observation, np.ndarray], None] | None,
    ) -> list[EpisodeResult]:
        observations = [env.reset(self.slots[slot][1]) for env, slot in zip(envs, slots, strict=True)]
        queues: list[deque] = [deque() for _ in envs]
        results: dict[int, EpisodeResult] = {}
        while len(results) < len(envs):
            replan = [i for i in range(len(envs)) if i not in results and not queues[i]]
            if replan:
                batch = processor.observation(
                    np.stack([observations[i].state for i in replan]),
                    [observations[i].instruction for i in replan],
                    np.stack([observations[i].image for i in replan]) if processor.image_size else None,
                    {
                        name: np.stack([observations[i].extra_images[name] for i in replan])
                        for name in processor.extra_cameras
                    },
                )
                noise = torch.randn(len(replan), processor.chunk_length, processor.action_dim, generator=generator)
                chunks = processor.unnormalize_actions(sample_actions(policy, batch, noise, mode)).numpy()
                for row, i in enumerate(replan):
                    queues[i].extend(chunks[row, :n_act])
            for i, env in enumerate(envs):
                if i in results:
                    continue
                action = queues[i].popleft()
                if record is not None:
                    record(slots[i], observations[i], action)
                # render only where the next step re-plans: the image is needed nowhere else
                observations[i], success, done = env.step(action, render=not queues[i])
                if done or env.steps == self.max_episode_steps:
                    results[i] = EpisodeResult(*self.slots[slots[i]], success, env.steps)
                    finished()
        return [results[i] for i in range(len(envs))]

    def close(self) -> None:
        for env in self._envs:
            env.close()
        self._envs = []


__all__ = ["ClosedLoopEvaluator"]
