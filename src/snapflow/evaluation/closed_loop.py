"""Closed-loop success on a benchmark: the episodes of all tasks run side by side, one batched policy call for every
environment that needs a new chunk, so inference uses every core while environments step. At most ``max_envs``
environments are alive at once (a Meta-World environment holds ~21 MB: 500 episodes side by side took 10.5 GB, and
two such evaluations on one 24 GB machine were killed for memory); more episodes run in waves of ``max_envs``."""

from __future__ import annotations

from collections import deque
from collections.abc import Callable

import numpy as np
import torch
from tqdm.auto import tqdm

from snapflow.envs.base import Benchmark, Environment, Observation
from snapflow.evaluation.results import EpisodeResult
from snapflow.flow.modes import SamplingMode
from snapflow.flow.solver import sample_actions
from snapflow.policies.processor import Processor
from snapflow.protocol import FlowPolicy

MAX_ENVS = 200  # the demo's 200 episodes in one wave, ~4 GB of Meta-World environments


class ClosedLoopEvaluator:
    """Runs every (task, episode) slot of the benchmark's evaluation split, for one policy and mode per ``run``.

    Slots run in waves of at most ``max_envs`` environments, in slot order, drawing the noise from one generator
    across waves: results depend on ``max_envs`` only when there are more slots than it. When every slot fits in one
    wave, its environments are kept and reused across runs (policies and modes); otherwise each wave makes its own and
    closes them when it ends.
    """

    def __init__(
        self,
        benchmark: Benchmark,
        tasks: list[str],
        episodes_per_task: int,
        image_size: int | None = None,
        max_envs: int = MAX_ENVS,
    ) -> None:
        benchmark.check_tasks(tasks)
        available = benchmark.num_variations("eval")
        if not 1 <= episodes_per_task <= available:
            raise ValueError(
                f"episodes per task must be in [1, {available}] ({benchmark.name}'s evaluation variations), got {episodes_per_task}"
            )
        if max_envs < 1:
            raise ValueError(f"max_envs must be at least 1, got {max_envs}")
        self.benchmark, self.image_size, self.max_envs = benchmark, image_size, max_envs
        self.slots = [(task, variation) for task in tasks for variation in range(episodes_per_task)]
        self._kept: list[Environment] | None = None  # the single wave's environments, reused across runs

    def _environments(self, slots: list[tuple[str, int]]) -> list[Environment]:
        if self._kept is not None:
            return self._kept
        envs = [self.benchmark.make_env(task, "eval", self.image_size) for task, _ in slots]
        if len(slots) == len(self.slots):
            self._kept = envs
        return envs

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
    ) -> list[EpisodeResult]:
        """Roll out every slot to success or the step limit, re-planning a chunk every ``n_act`` actions;
        ``record(slot, observation, action)`` is called before each step (to trace episodes)."""
        if not 1 <= n_act <= processor.chunk_length:
            raise ValueError(f"n_act must be in [1, {processor.chunk_length}] (the policy's chunk length), got {n_act}")
        policy.eval()
        generator = torch.Generator().manual_seed(seed)
        results: list[EpisodeResult] = []
        with tqdm(total=len(self.slots), desc=f"closed loop {mode.name}", disable=not progress, leave=False) as bar:
            for start in range(0, len(self.slots), self.max_envs):
                slots = self.slots[start : start + self.max_envs]
                envs = self._environments(slots)
                try:
                    results += self._run_wave(
                        envs, slots, start, policy, processor, mode, n_act, generator, bar.update, record
                    )
                finally:
                    if envs is not self._kept:
                        for env in envs:
                            env.close()
        return results

    def _run_wave(
        self,
        envs: list[Environment],
        slots: list[tuple[str, int]],
        first_slot: int,
        policy: FlowPolicy,
        processor: Processor,
        mode: SamplingMode,
        n_act: int,
        generator: torch.Generator,
        finished: Callable[[], object],
        record: Callable[[int, Observation, np.ndarray], None] | None,
    ) -> list[EpisodeResult]:
        observations = [env.reset(variation) for env, (_, variation) in zip(envs, slots, strict=True)]
        queues: list[deque] = [deque() for _ in envs]
        results: dict[int, EpisodeResult] = {}
        while len(results) < len(envs):
            replan = [i for i in range(len(envs)) if i not in results and not queues[i]]
            if replan:
                batch = processor.observation(
                    np.stack([observations[i].state for i in replan]),
                    [observations[i].instruction for i in replan],
                    np.stack([observations[i].image for i in replan]) if processor.image_size else None,
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
                    record(first_slot + i, observations[i], action)
                # render only where the next step re-plans: the image is needed nowhere else
                observations[i], success, done = env.step(action, render=not queues[i])
                if done:
                    results[i] = EpisodeResult(slots[i][0], slots[i][1], success, env.steps)
                    finished()
        return [results[i] for i in range(len(envs))]

    def close(self) -> None:
        """Close the environments kept for reuse (a multi-wave evaluation keeps none)."""
        for env in self._kept or []:
            env.close()
        self._kept = None


__all__ = ["MAX_ENVS", "ClosedLoopEvaluator"]
