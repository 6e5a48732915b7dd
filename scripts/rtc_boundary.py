"""The chunk-boundary tables of docs/results/rtc-boundary-tiny-smolvla*: real-time chunking with a 10-step teacher
and a one-step SnapFlow student, and one distilled with known prefixes (real-time chunking trained in), on recorded
chunks of a tiny SmolVLA (offline, CPU, about three minutes on one core).

A tiny SmolVLA teacher (the tests' SmolVLM, written locally) learns by flow matching a LeRobotDataset whose actions
take one of two far-apart values by a coin the observation does not show (so chunks planned from fresh noise land
in either mode, and a chunk boundary can jump): each action by its own coin, or (``--mode-per-episode``) an episode
keeping to one mode, as a demonstrator keeps to one way, so that a chunk's first actions tell its others. snapflow
distils it; the boundary is measured on an episode neither saw. Run from the repository root:
``python scripts/rtc_boundary.py [OUTPUT] [--mode-per-episode] [--seeds N]``.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the tests' tiny builders

CHUNK, EXECUTED, DELAY, MAX_DELAY = 8, 4, 2, 4
TEACHER_STEPS, STUDENT_STEPS = 400, 300


def one_seed(work: Path, seed: int) -> list:
    """The rows of one seed: a teacher, its student and its student trained for RTC, on the data in ``work``."""
    from dataclasses import replace

    from lerobot.datasets.lerobot_dataset import LeRobotDataset
    from lerobot.policies.factory import make_pre_post_processors
    from torch.utils.data import default_collate

    from snapflow.adapters.lerobot.plugin import student_policy
    from snapflow.benchmark.rtc import boundary_jumps
    from snapflow.training.config import TrainConfig
    from snapflow.training.lerobot import distill_lerobot, train_lerobot_teacher
    from snapflow.training.recipes import DistillSettings

    torch.manual_seed(seed)
    runs, data = work / f"seed-{seed}", work / "data"
    steps = {"batch_size": 16, "learning_rate": 1e-3, "warmup_steps": 20, "checkpoint_every": 10000, "seed": seed}
    teacher = TrainConfig(steps=TEACHER_STEPS, **steps)
    train_lerobot_teacher("smolvla", data, "local/tiny", runs / "teacher", teacher, chunk_size=CHUNK, val_fraction=0.0)
    student = TrainConfig(steps=STUDENT_STEPS, **steps)
    settings = DistillSettings(consistency_weight=1.0)
    teacher_folder = str(runs / "teacher" / "lerobot_policy")
    distill_lerobot(teacher_folder, data, "local/tiny", runs / "student", student, settings)
    known = replace(settings, rtc_max_delay=MAX_DELAY)  # the same recipe and budget, each row's prefix given
    distill_lerobot(teacher_folder, data, "local/tiny", runs / "trained", student, known)
    student_class = student_policy("smolvla")
    policy = student_class.from_pretrained(runs / "student" / "lerobot_policy")
    trained = student_class.from_pretrained(runs / "trained" / "lerobot_policy")
    preprocessor, _ = make_pre_post_processors(policy.config, pretrained_path=str(runs / "student" / "lerobot_policy"))
    held = LeRobotDataset("local/held", root=work / "held")
    batch = preprocessor(default_collate([held[index] for index in range(len(held))]))
    return boundary_jumps(policy, batch, EXECUTED, DELAY, seed=seed, trained=trained)


def main(output: Path, mode_per_episode: bool, seeds: int) -> None:
    from snapflow.benchmark.rtc import write_boundary_report
    from snapflow.reporting.machine import versions
    from tests.lerobot_tiny import write_tiny_dataset

    torch.set_num_threads(1)
    work = Path(tempfile.mkdtemp())
    modes = {"bimodal": True, "mode_per_episode": mode_per_episode}
    write_tiny_dataset(work / "data", episodes=6, frames=24, **modes)
    write_tiny_dataset(work / "held", repo_id="local/held", episodes=1, frames=40, seed=1, **modes)
    rows = [one_seed(work, seed) for seed in range(seeds)]
    recorded = {
        "policy": f"tiny SmolVLA (SmolVLM 64-wide, 2 layers; ~190k parameters), teacher {TEACHER_STEPS} flow-matching "
        f"steps, student {STUDENT_STEPS} SnapFlow steps (alpha 0.5, lambda 1); the student trained for RTC: the same "
        f"{STUDENT_STEPS} steps with each row's first 0..{MAX_DELAY} actions given (distill.rtc_max_delay {MAX_DELAY})",
        "data": "bimodal tiny LeRobotDataset (tests/lerobot_tiny.py), "
        + (
            "an episode keeping to one mode, twin episodes seeing the same frames in opposite modes"
            if mode_per_episode
            else "each action's mode by its own coin"
        )
        + "; one held-out episode of 40 frames",
        "seeds": list(range(seeds)),
        "chunk_size": CHUNK,
        "executed_per_chunk": EXECUTED,
        "inference_delay": DELAY,
        "execution_horizon": CHUNK - EXECUTED,
        "previous_chunk": "the student's teacher-10 chunk planned executed_per_chunk frames earlier",
        "units": "L2 over the 4 action dimensions, normalised; ms: batch-1 predict_action_chunk, one CPU thread",
        "versions": versions(),
    }
    write_boundary_report(rows, recorded, output)
    print((output / "rtc_boundary.md").read_text())


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("output", nargs="?", type=Path, help="the result folder (default: the committed one)")
    parser.add_argument("--mode-per-episode", action="store_true", help="an episode keeps to one mode")
    parser.add_argument("--seeds", type=int, default=3, help="how many seeds, each its own teacher and students")
    args = parser.parse_args()
    default = "docs/results/rtc-boundary-tiny-smolvla" + ("-episode-modes" if args.mode_per_episode else "")
    main(args.output or Path(default), args.mode_per_episode, args.seeds)
