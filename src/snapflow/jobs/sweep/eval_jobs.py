"""A sweep's evaluation as a job: one (policy, sampling mode, actions per chunk, episodes per task), by snapflow's
evaluator or LeRobot's own lerobot-eval."""

from __future__ import annotations

import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

from snapflow.envs.factory import make_benchmark
from snapflow.evaluation.config import OFFLINE_SAMPLES
from snapflow.evaluation.episode_log import logged_episodes
from snapflow.evaluation.pipeline import evaluate
from snapflow.flow.modes import SamplingMode
from snapflow.flow.realtime_settings import RealTimeChunking
from snapflow.jobs.runner import Job, JobProgress, holds_record_of, is_started, record
from snapflow.jobs.sweep.data_jobs import held_out_with_frames
from snapflow.jobs.sweep.specs import EVALUATORS
from snapflow.jobs.sweep.training_jobs import TrainJob
from snapflow.reporting.files import write_json, write_text
from snapflow.reporting.records import as_record
from snapflow.sources import open_policy
from snapflow.training.config import VAL_FRACTION

KEPT_JOB = "job.json"  # beside a row's kept progress (tasks or episode log): the record of the job it belongs to


@dataclass(frozen=True)
class EvalJob(Job):
    """One (policy, sampling mode, actions per chunk, episodes per task): closed-loop success and offline metrics on
    the held-out demonstrations; its record, at ``path``, holds the evaluation row."""

    kind: ClassVar[str] = "eval"
    uses_gpu: ClassVar[bool] = True
    policy: TrainJob
    mode: SamplingMode
    n_act: int
    episodes_per_task: int
    path: Path
    ledger: Path | None = None
    first_variation: int = 0  # each task's episodes from this evaluation variation on
    evaluator: str = EVALUATORS[0]  # snapflow's evaluator, or LeRobot's lerobot-eval (no offline metrics)
    tasks: tuple[str, ...] = ()  # a subset of the data's tasks (empty: every one)
    max_episode_steps: int | None = None  # every episode cut there (None: the benchmark's own limit)
    rtc: RealTimeChunking | None = None  # chunks planned under an inference delay, continuing each other

    @property
    def by_lerobot_eval(self) -> bool:
        """Whether LeRobot's ``lerobot-eval`` runs its episodes rather than snapflow's evaluator."""
        return self.evaluator != EVALUATORS[0]

    def settings(self) -> dict[str, Any]:
        return {
            "mode": as_record(self.mode),
            "n_act": self.n_act,
            "episodes_per_task": self.episodes_per_task,
            "seed": self.policy.seed,
            **({} if self.by_lerobot_eval else {"offline_samples": OFFLINE_SAMPLES}),
            # only where set: the records made before they could be chosen are of the first variations, by snapflow's
            **({"first_variation": self.first_variation} if self.first_variation else {}),
            **({"evaluator": self.evaluator} if self.by_lerobot_eval else {}),
            **({"tasks": list(self.tasks)} if self.tasks else {}),
            **({"max_episode_steps": self.max_episode_steps} if self.max_episode_steps is not None else {}),
            **({"rtc": self.rtc.to_dict()} if self.rtc is not None else {}),
        }

    @property
    def task_names(self) -> list[str]:
        """The tasks its episodes run on."""
        return list(self.tasks or self.policy.data.data.tasks)

    @property
    def dependencies(self) -> tuple[Job, ...]:
        return (self.policy, self.policy.data)

    @property
    def record_path(self) -> Path:
        return self.path

    @property
    def ledger_path(self) -> Path | None:
        return self.ledger

    @property
    def episodes_dir(self) -> Path:
        """Where its episodes are logged as they finish (by lerobot-eval: each task's run): an interrupted evaluation
        goes on from them."""
        return self.path.with_name(f"{self.path.stem}.episodes")

    @property
    def outputs(self) -> tuple[Path, ...]:
        return (self.episodes_dir,)

    def run(self) -> dict[str, Any]:
        if self.by_lerobot_eval:
            return self._run_lerobot_eval()
        collected = self.policy.data
        loaded = open_policy(str(self.policy.policy_path))
        # lerobot-train records no held-out share: it trained on its teacher's split, every run's here
        val_fraction = VAL_FRACTION if self.policy.trainer == "lerobot-train" else None
        data, data_held_out = collected.directory, False
        if collected.data.video is not None and loaded.processor.image_size:  # frames kept as video alone
            data, data_held_out = held_out_with_frames(collected, loaded.held_out_share(val_fraction)), True
        # the runner clears the log of a run with other settings, so what is left is this evaluation's to resume
        report = evaluate(
            [(self.mode.name, loaded, self.mode)],
            make_benchmark(collected.data.env),
            self.task_names,
            self.episodes_per_task,
            self.n_act,
            data,
            seed=self.policy.seed,
            progress=False,
            timing=False,
            episode_logs=self.episodes_dir,
            resume=True,
            first_variation=self.first_variation,
            max_episode_steps=self.max_episode_steps,
            val_fraction=val_fraction,
            kept_logs=self._claim_kept_progress(),
            rtc=self.rtc,
            data_held_out=data_held_out,
        )
        return report.rows[self.mode.name].to_dict()

    def reads_outputs_of(self, dependency: Job) -> bool:
        """lerobot-eval reads the policy alone: the demonstrations (offline metrics) are snapflow's evaluator's."""
        return not self.by_lerobot_eval or dependency != self.policy.data

    @property
    def kept_progress(self) -> Path | None:
        """Beside the ledger's record, what an unfinished row has finished, and the job it belongs to (``job.json``),
        so that another machine goes on from there: by lerobot-eval each finished task's ``eval_info.json`` and wall
        time, by snapflow's evaluator its episode log, whole after each wave (a LIBERO row of 400 episodes takes hours)."""
        return None if self.ledger is None else self.ledger.with_suffix("")

    def _kept_by_this_job(self) -> bool:
        kept = self.kept_progress
        return kept is not None and holds_record_of(kept / KEPT_JOB, self)

    def _claim_kept_progress(self) -> Path | None:
        """The folder of kept progress, emptied first where another job's settings kept it."""
        kept = self.kept_progress
        if kept is not None and not self._kept_by_this_job():
            shutil.rmtree(kept, ignore_errors=True)
            write_json(kept / KEPT_JOB, record(self))
        return kept

    def progress(self) -> JobProgress | None:
        """The episodes finished here, or kept by another machine: whichever is further."""
        folders = ([self.episodes_dir] if is_started(self) else []) + (
            [self.kept_progress] if self._kept_by_this_job() and self.kept_progress is not None else []
        )
        if not folders:
            return None
        if self.by_lerobot_eval:
            from snapflow.evaluation.lerobot_eval import finished_tasks

            done = max(len(finished_tasks(folder)) * self.episodes_per_task for folder in folders)
        else:
            done = max(logged_episodes(folder) for folder in folders)
        return JobProgress(done, len(self.task_names) * self.episodes_per_task, "episodes")

    def restore_progress(self) -> bool:
        if not self._kept_by_this_job():
            return False
        assert self.kept_progress is not None
        if self.by_lerobot_eval:
            from snapflow.evaluation.lerobot_eval import restore_kept_tasks

            return bool(restore_kept_tasks(self.kept_progress, self.episodes_dir))
        logs = sorted(self.kept_progress.glob("*.jsonl"))
        for log in logs:
            write_text(self.episodes_dir / log.name, log.read_text())
        return bool(logs)

    def _run_lerobot_eval(self) -> dict[str, Any]:
        """LeRobot's ``lerobot-eval`` on each task, its ``eval_info.json`` files kept beside the ledger's record."""
        import torch

        from snapflow.evaluation.lerobot_eval import run_lerobot_eval

        data = self.policy.data.data
        kept = self._claim_kept_progress()  # tasks another job's settings kept are not this one's
        row = run_lerobot_eval(
            self.policy.policy_path,
            self.task_names,
            self.episodes_per_task,
            data.image_size,
            self.n_act,
            self.mode,
            self.episodes_dir,
            threads=torch.get_num_threads(),
            kept=kept,
            max_episode_steps=self.max_episode_steps,
        )
        return row.to_dict()

    def describe(self) -> str:
        policy = self.policy
        by = f", by {self.evaluator}" if self.by_lerobot_eval else ""
        # named only where it is not the first, so that the descriptions of every committed sweep read as they did
        start = f"; from variation {self.first_variation}" if self.first_variation else ""
        delay = f"; delay {self.rtc.delay}, rtc {self.rtc.kind}" if self.rtc is not None else ""
        return (
            f"{policy.sweep}: evaluate {policy.run_name} seed {policy.seed} "
            f"({self.mode.name}; n_act {self.n_act}{start}{by}{delay})"
        )


__all__ = ["KEPT_JOB", "EvalJob"]
