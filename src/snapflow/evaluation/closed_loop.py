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
from snapflow.evaluation.switches import switch_smoothness
from snapflow.flow.known_prefix import per_action_times_refusal
from snapflow.flow.modes import SamplingMode
from snapflow.flow.realtime import RealTimeChunking, sample_chunk_continuing
from snapflow.flow.solver import sample_actions
from snapflow.policies.processor import Processor
from snapflow.protocol import FlowPolicy


class ClosedLoopEvaluator:
    """Runs every (task, episode) slot of the benchmark's evaluation split, for one policy and mode per ``run``.

    A task's episodes start from its evaluation variations ``first_variation`` on (LIBERO's fixed initial states, in
    order). Each task gets ``max_envs // len(tasks)`` environments (at least one), made at the first run and kept for the
    next ones: episodes run in waves of that many variations per task, every task side by side, the noise drawn
    from one generator across waves. Results depend on ``max_envs`` only when a task has more episodes than that, or
    when there are more tasks than ``max_envs``: then the tasks run in groups of ``max_envs``, one group's waves after
    the other's, each group's environments closed before the next group's are made.
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
        # more tasks than max_envs (LIBERO's four suites: 40): their environments exist a group of tasks at a time,
        # the groups one after another (40 LIBERO environments with cameras side by side ran 24 GB out of memory)
        size = min(len(tasks), max_envs)
        self.task_groups = [range(start, min(start + size, len(tasks))) for start in range(0, len(tasks), size)]
        # wave -> (slot, environment index in its group) pairs, task-major as the slots; with one group (every task
        # at once) one wave is the old all-at-once loop
        self.waves = [
            [
                (t * episodes_per_task + v, (t - group.start) * self.envs_per_task + v - first)
                for t in group
                for v in range(first, min(first + self.envs_per_task, episodes_per_task))
            ]
            for group in self.task_groups
            for first in range(0, episodes_per_task, self.envs_per_task)
        ]
        self.wave_groups = [
            g for g, _ in enumerate(self.task_groups) for _ in range(0, episodes_per_task, self.envs_per_task)
        ]
        self._envs: list[Environment] = []
        self._envs_group: int | None = None

    def _environments(self, group: int) -> list[Environment]:
        """The environments of task group ``group``, made when first needed; another group's are closed first."""
        if self._envs_group != group:
            self.close()
            self._envs = [
                self.benchmark.make_env(self.tasks[task], "eval", self.image_size, self.extra_cameras)
                for task in self.task_groups[group]
                for _ in range(self.envs_per_task)
            ]
            self._envs_group = group
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
        rtc: RealTimeChunking | None = None,
        switches: bool = False,
    ) -> list[EpisodeResult]:
        """Roll out every slot to success or the step limit, re-planning a chunk every ``n_act`` actions;
        ``record(slot, observation, action)`` is called before each step (to trace episodes). With ``log``, each
        finished wave is appended to it, and the waves it already holds are taken from it, not run again (nor
        recorded): the run goes on from the noise generator's state after the last of them.

        With ``rtc`` (real-time chunking under an inference delay d = ``rtc.delay``) the first chunk executes its
        actions 0..n_act-1; afterwards a new chunk is planned when d actions remain queued, from the observation of
        that moment, continuing the previous chunk's unexecuted (normalised) actions, whose first d are executed
        while it is computed, and the queue goes on with its actions d..d+n_act-1 (so d <= n_act and
        n_act + d <= the chunk length). Either way each chunk executes n_act actions: an episode's chunk switches
        are at its steps n_act, 2 n_act, ... (the step whose action ``record`` is given first of a new chunk). With
        ``switches``, each episode's result holds how smoothly its chunks joined there (:mod:`.switches`)."""
        if not 1 <= n_act <= processor.chunk_length:
            raise InvalidInputError(
                f"n_act must be in [1, {processor.chunk_length}] (the policy's chunk length), got {n_act}"
            )
        if rtc is not None:
            rtc = check_rtc(rtc, policy, mode, n_act, processor.chunk_length)
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
                    envs = self._environments(self.wave_groups[index])  # none made for a finished log
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
                        rtc,
                        switches,
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
        rtc: RealTimeChunking | None = None,
        switches: bool = False,
    ) -> list[EpisodeResult]:
        observations = [env.reset(self.slots[slot][1]) for env, slot in zip(envs, slots, strict=True)]
        queues: list[deque] = [deque() for _ in envs]
        # with rtc: where each queued action comes from (its normalised chunk, its index there), and where the rest of
        # the last executed one's chunk starts: a next chunk continues the chunk its next action would come from
        sources: list[deque] = [deque() for _ in envs]
        rests: list[tuple[torch.Tensor, int] | None] = [None for _ in envs]
        results: dict[int, EpisodeResult] = {}
        executed: list[list[np.ndarray]] = [[] for _ in envs]  # each episode's actions, where switches are measured
        delay = None if rtc is None else rtc.delay
        while len(results) < len(envs):
            alive = [i for i in range(len(envs)) if i not in results]
            first = [i for i in alive if not queues[i] and (rtc is None or rests[i] is None)]
            if first:
                batch = _observation_batch(processor, [observations[i] for i in first])
                noise = torch.randn(len(first), processor.chunk_length, processor.action_dim, generator=generator)
                normalised = sample_actions(policy, batch, noise, mode)
                chunks = processor.unnormalize_actions(normalised).numpy()
                for row, i in enumerate(first):
                    queues[i].extend(chunks[row, :n_act])
                    if rtc is not None:
                        sources[i].extend((normalised[row], index) for index in range(n_act))
            continuing = [] if rtc is None else [i for i in alive if len(queues[i]) == delay]
            if continuing:
                self._continue_chunks(
                    [observations[i] for i in continuing],
                    [sources[i][0] if sources[i] else rests[i] for i in continuing],
                    [queues[i] for i in continuing],
                    [sources[i] for i in continuing],
                    policy,
                    processor,
                    mode,
                    n_act,
                    generator,
                    rtc,
                )
            for i in alive:
                action = queues[i].popleft()
                if rtc is not None:
                    chunk, index = sources[i].popleft()
                    rests[i] = (chunk, index + 1)
                if record is not None:
                    record(slots[i], observations[i], action)
                if switches:
                    executed[i].append(action)
                # render only where the next step re-plans: the image is needed nowhere else
                replans = not queues[i] if rtc is None else len(queues[i]) == delay
                observations[i], success, done = envs[i].step(action, render=replans)
                if done or envs[i].steps == self.max_episode_steps:
                    smoothness = switch_smoothness(np.stack(executed[i]), n_act) if switches else None
                    results[i] = EpisodeResult(
                        *self.slots[slots[i]], success, envs[i].steps, envs[i].path_mode(), smoothness
                    )
                    finished()
        return [results[i] for i in range(len(envs))]

    @staticmethod
    def _continue_chunks(
        observations: list[Observation],
        rests: list[tuple[torch.Tensor, int]],
        queues: list[deque],
        sources: list[deque],
        policy: FlowPolicy,
        processor: Processor,
        mode: SamplingMode,
        n_act: int,
        generator: torch.Generator,
        rtc: RealTimeChunking,
    ) -> None:
        """Plan the next chunks of environments with ``rtc.delay`` actions queued, each continuing the rest of a
        previous chunk (``rests``: the normalised chunk and the index of its next action), and queue their actions
        d..d+n_act-1."""
        noise = torch.randn(len(observations), processor.chunk_length, processor.action_dim, generator=generator)
        previous = torch.stack([chunk[index:] for chunk, index in rests])
        context = policy.encode(_observation_batch(processor, observations))
        normalised = sample_chunk_continuing(policy, context, noise, mode, previous, rtc)
        chunks = processor.unnormalize_actions(normalised).numpy()
        executed = range(rtc.delay, rtc.delay + n_act)
        for row, (queue, source) in enumerate(zip(queues, sources, strict=True)):
            queue.extend(chunks[row, executed.start : executed.stop])
            source.extend((normalised[row], index) for index in executed)

    def close(self) -> None:
        for env in self._envs:
            env.close()
        self._envs, self._envs_group = [], None


def _observation_batch(processor: Processor, observations: list[Observation]) -> object:
    """The policy's inputs for a batch of observations."""
    return processor.observation(
        np.stack([observation.state for observation in observations]),
        [observation.instruction for observation in observations],
        np.stack([observation.image for observation in observations]) if processor.image_size else None,
        {
            name: np.stack([observation.extra_images[name] for observation in observations])
            for name in processor.extra_cameras
        },
    )


def check_rtc(
    rtc: RealTimeChunking, policy: FlowPolicy, mode: SamplingMode, n_act: int, chunk_length: int
) -> RealTimeChunking:
    """The real-time chunking setting for ``mode`` (its kind resolved), or refuse one the evaluator cannot run with
    this policy, mode and ``n_act``."""
    rtc = rtc.for_mode(mode)
    if rtc.delay > n_act or n_act + rtc.delay > chunk_length:
        raise InvalidInputError(
            f"an inference delay of {rtc.delay} with n_act {n_act} needs delay <= n_act (a chunk is planned while "
            f"the previous one's last {rtc.delay} actions run) and n_act + delay <= the policy's chunk length "
            f"{chunk_length}"
        )
    refusal = per_action_times_refusal(policy) if rtc.kind == "trained" else None
    if refusal is not None:
        raise InvalidInputError(f"{refusal}: real-time chunking 'trained' needs a policy given a time per action")
    return rtc


__all__ = ["ClosedLoopEvaluator", "check_rtc"]
