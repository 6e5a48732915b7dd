"""Closed-loop success on a benchmark: all episodes of all tasks run side by side, one batched policy call for every
environment that needs a new chunk, so inference uses every core while environments step."""

from __future__ import annotations

from collections import deque
from collections.abc import Callable

import numpy as np
import torch
from tqdm.auto import tqdm

from snapflow.envs.base import Benchmark, Observation
from snapflow.evaluation.results import EpisodeResult
from snapflow.flow.modes import SamplingMode
from snapflow.flow.solver import sample_actions
from snapflow.policies.processor import Processor
from snapflow.protocol import FlowPolicy


class ClosedLoopEvaluator:
    """Holds one environment per (task, episode) on the benchmark's evaluation split, reused across policies and modes."""

    def __init__(
        self, benchmark: Benchmark, tasks: list[str], episodes_per_task: int, image_size: int | None = None
    ) -> None:
        benchmark.check_tasks(tasks)
        available = benchmark.num_variations("eval")
        if not 1 <= episodes_per_task <= available:
            raise ValueError(
                f"episodes per task must be in [1, {available}] ({benchmark.name}'s evaluation variations), got {episodes_per_task}"
            )
        self.slots = [(task, variation) for task in tasks for variation in range(episodes_per_task)]
        self.envs = [benchmark.make_env(task, "eval", image_size) for task, _ in self.slots]

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
        chunk_length = processor.chunk_length
        if not 1 <= n_act <= chunk_length:
            raise ValueError(f"n_act must be in [1, {chunk_length}] (the policy's chunk length), got {n_act}")
        policy.eval()
        generator = torch.Generator().manual_seed(seed)
        observations = [env.reset(variation) for env, (_, variation) in zip(self.envs, self.slots, strict=True)]
        queues: list[deque] = [deque() for _ in self.envs]
        results: dict[int, EpisodeResult] = {}
        bar = tqdm(total=len(self.envs), desc=f"closed loop {mode.name}", disable=not progress, leave=False)
        while len(results) < len(self.envs):
            replan = [i for i in range(len(self.envs)) if i not in results and not queues[i]]
            if replan:
                batch = processor.observation(
                    np.stack([observations[i].state for i in replan]),
                    [observations[i].instruction for i in replan],
                    np.stack([observations[i].image for i in replan]) if processor.image_size else None,
                )
                noise = torch.randn(len(replan), chunk_length, processor.action_dim, generator=generator)
                chunks = processor.unnormalize_actions(sample_actions(policy, batch, noise, mode)).numpy()
                for row, i in enumerate(replan):
                    queues[i].extend(chunks[row, :n_act])
            for i, env in enumerate(self.envs):
                if i in results:
                    continue
                action = queues[i].popleft()
                if record is not None:
                    record(i, observations[i], action)
                # render only where the next step re-plans: the image is needed nowhere else
                observations[i], success, done = env.step(action, render=not queues[i])
                if done:
                    results[i] = EpisodeResult(self.slots[i][0], self.slots[i][1], success, env.steps)
                    bar.update()
        bar.close()
        return [results[i] for i in range(len(self.envs))]

    def close(self) -> None:
        for env in self.envs:
            env.close()


__all__ = ["ClosedLoopEvaluator"]
