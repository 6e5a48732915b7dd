"""A LeRobot teacher made ready for ``lerobot-train`` to distil: the same weights typed as its SnapFlow student
(``snapflow_<type>``, phi_s at zero, ``distilled`` false), the distillation settings in its config's ``distill``,
the teacher's processors beside it. ``lerobot-train --policy.path=<that folder>`` then runs SnapFlow distillation with LeRobot's
own trainer, optimiser, Accelerate, logging and hub push (the student type's ``forward`` is the objective,
:mod:`snapflow.adapters.lerobot.plugin.modeling_snapflow`)."""

from __future__ import annotations

import hashlib
import json
import shutil
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from snapflow.adapters.lerobot.local_vlm import bundle_vlm
from snapflow.adapters.lerobot.plugin.configuration_snapflow import SnapFlowSampling, check_student_settings
from snapflow.adapters.lerobot_commands import run_lerobot_command
from snapflow.adapters.lerobot_config import VIDEO_BACKEND
from snapflow.errors import InvalidInputError
from snapflow.objective.settings import DistillSettings
from snapflow.policies.loaded import CheckpointError
from snapflow.sources import open_policy
from snapflow.training.config import TrainConfig
from snapflow.training.lerobot_progress import CheckpointKeeper, install_kept_progress


def write_student(
    policy_path: str,
    output: str | Path,
    settings: DistillSettings | None = None,
    preprocessor_overrides: dict[str, Any] | None = None,
) -> Path:
    """The LeRobot policy of a declared type at ``policy_path`` (hub id or folder) written to ``output`` as its SnapFlow
    student, ready for ``lerobot-train --policy.path=output``: its weights with phi_s at zero (bit for bit the
    teacher), its config typed ``snapflow_<type>`` with ``distilled`` false (it refuses ``snapflow-N`` until trained)
    and ``settings`` (default: the paper's) as its ``distill``, and the teacher's own processors (built
    from its config when its folder has none; ``lerobot-train`` gives them the dataset's statistics). A SmolVLM the
    teacher reads from a local folder is copied inside, its tokenizer carried by the pre-processor
    (:func:`~snapflow.adapters.lerobot.local_vlm.bundle_vlm`), so that LeRobot's tools take ``output`` from any
    working directory.

    A student given as ``policy_path`` keeps its phi_s and its ``distilled`` record: training it again continues
    the distillation, a run of its own (its count of steps, ``steps_distilled``, and the steps a schedule spreads
    over, ``distill_steps``, start again)."""
    from snapflow.adapters.lerobot.plugin import student_config
    from snapflow.training.lerobot import policy_processors

    settings = settings or DistillSettings()
    check_student_settings(settings)
    opened = open_policy(policy_path)
    if opened.exported:
        raise CheckpointError(f"{policy_path} is an {opened.export['format']} export: it runs, it does not train")
    policy = opened.policy.policy
    config = student_config(policy.config)
    if not isinstance(policy.config, SnapFlowSampling):
        config.distilled = False
    config.distill, config.distill_steps, config.steps_distilled = settings, None, 0
    output = Path(output)
    policy.save_pretrained(output)
    config._save_pretrained(output)
    for processor in policy_processors(policy, policy_path, None, preprocessor_overrides):
        processor.save_pretrained(output)
    bundle_vlm(output)  # its own SmolVLM and tokenizer inside: lerobot-train runs on it from any working directory
    return output


#: where ``lerobot-train`` leaves its last checkpoint's policy, inside its ``--output_dir``
LAST_CHECKPOINT = Path("checkpoints") / "last" / "pretrained_model"


def lerobot_train_arguments(config: TrainConfig, training_episodes: list[int] | None) -> list[str]:
    """``config`` as ``lerobot-train`` flags (its AdamW, warm-up and cosine decay to ``min_learning_rate_ratio`` of
    the peak, clipping, checkpoints, logs; the steps a schedule of target steps spreads over, the student's
    ``distill_steps``; ``training_episodes``: the dataset's episodes it trains on, None for all).
    What LeRobot's trainer has no flag for (a weight average, mixed precision from here) is refused by name."""
    if config.ema_decay is not None or config.mixed_precision != "no":
        raise InvalidInputError(
            "lerobot-train keeps no weight average and takes its precision from Accelerate's own launch: give a "
            "lerobot-train student ema_decay unset and mixed_precision 'no'"
        )
    arguments = [
        f"--steps={config.steps}",
        f"--batch_size={config.batch_size}",
        f"--seed={config.seed}",
        f"--save_freq={config.checkpoint_every}",
        f"--log_freq={config.log_every}",
        f"--policy.optimizer_lr={config.learning_rate}",
        f"--policy.optimizer_weight_decay={config.weight_decay}",
        f"--policy.optimizer_grad_clip_norm={config.grad_clip}",
        f"--policy.scheduler_warmup_steps={config.warmup_steps}",
        f"--policy.scheduler_decay_steps={config.steps}",
        f"--policy.scheduler_decay_lr={config.learning_rate * config.min_learning_rate_ratio}",
        f"--policy.distill_steps={config.steps}",
    ]
    if training_episodes is not None:
        arguments.append(f"--dataset.episodes=[{','.join(str(episode) for episode in training_episodes)}]")
    return arguments


def lerobot_train_run(student: str | Path, config: TrainConfig, training_episodes: list[int] | None) -> dict[str, Any]:
    """What a ``lerobot-train`` run of the student folder ``student`` is, the same on every machine (no path): its
    training flags, the student's distillation settings and a digest of the weights it starts from (its teacher's).
    Kept progress resumes only the same run."""
    distill = json.loads((Path(student) / "config.json").read_text()).get("distill")
    weights = hashlib.sha256()
    with (Path(student) / "model.safetensors").open("rb") as file:
        for block in iter(lambda: file.read(1 << 24), b""):
            weights.update(block)
    return {
        "flags": lerobot_train_arguments(config, training_episodes),
        "distill": distill,
        "weights": weights.hexdigest(),
    }


@dataclass(frozen=True)
class LeRobotTrainResult:
    """A finished ``lerobot-train`` run: its policy folder and its training time over all its attempts."""

    policy: Path
    wall_time_s: float


def run_lerobot_train(
    student: str | Path,
    dataset_root: str | Path,
    repo_id: str,
    output: str | Path,
    config: TrainConfig,
    training_episodes: list[int] | None = None,
    device: str = "cpu",
    threads: int | None = None,
    keep_progress: Path | None = None,
) -> LeRobotTrainResult:
    """Distil the student folder ``student`` (:func:`write_student`'s) with LeRobot's own ``lerobot-train``, run as a
    subprocess of this interpreter's environment, into ``output``; an interrupted run resumes from its last
    checkpoint. Returns the distilled policy's folder (``output/checkpoints/last/pretrained_model``) and the run's
    training time, the attempts before this one included (each checkpoint stamped with it). ``threads``:
    the torch threads of the subprocess (``OMP_NUM_THREADS``). ``keep_progress``: a folder that keeps a copy of each
    checkpoint as it is saved (:mod:`snapflow.training.lerobot_progress`), to commit or carry to another machine; a
    run folder without a checkpoint continues from the one kept there."""
    from snapflow.adapters.lerobot_types import PLUGIN_LEROBOT, lerobot_loads_plugins

    if not lerobot_loads_plugins():
        raise InvalidInputError(f"lerobot-train imports snapflow's student types from lerobot {PLUGIN_LEROBOT} on")
    output = Path(output)
    last = output / LAST_CHECKPOINT
    # what kept progress belongs to: read (a digest of the weights) only where progress is kept
    run = lerobot_train_run(student, config, training_episodes) if keep_progress is not None else {}
    if not (last / "train_config.json").is_file():
        if output.exists():  # started, but stopped before its first checkpoint: nothing to resume
            shutil.rmtree(output)
        if keep_progress is not None:
            install_kept_progress(keep_progress, output, student, run)
    if (last / "train_config.json").is_file():  # LeRobot's own resume: its saved config, optimiser and step
        # where the run is now, not where its config says it was (a checkpoint kept on another machine)
        arguments = [f"--config_path={last / 'train_config.json'}", "--resume=true", f"--output_dir={output}"]
        arguments.append(f"--dataset.root={dataset_root}")
    else:
        arguments = [
            f"--policy.path={student}",
            f"--dataset.repo_id={repo_id}",
            f"--dataset.root={dataset_root}",
            f"--dataset.video_backend={VIDEO_BACKEND}",
            f"--output_dir={output}",
            "--num_workers=0",
            "--wandb.enable=false",
            f"--policy.device={device}",
            "--policy.push_to_hub=false",
            *lerobot_train_arguments(config, training_episodes),
        ]
    with CheckpointKeeper(output, keep_progress, student, run) as keeper:
        run_lerobot_command(
            "lerobot-train",
            [str(Path(sys.executable).with_name("lerobot-train")), *arguments],
            output.parent / f"{output.name}.log",  # beside the run: lerobot-train refuses an output_dir that exists
            threads,
            append=True,  # a resumed run's lines follow the interrupted one's
        )
    return LeRobotTrainResult(last, keeper.elapsed)


__all__ = [
    "LAST_CHECKPOINT",
    "LeRobotTrainResult",
    "lerobot_train_arguments",
    "lerobot_train_run",
    "run_lerobot_train",
    "write_student",
]
