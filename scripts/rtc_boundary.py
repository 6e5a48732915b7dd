"""The chunk-boundary table of docs/results/rtc-boundary-tiny-smolvla: real-time chunking with a 10-step teacher and
a one-step SnapFlow student, on recorded chunks of a tiny SmolVLA (offline, CPU, about two minutes on one core).

A tiny SmolVLA teacher (the tests' SmolVLM, written locally) learns by flow matching a LeRobotDataset whose actions
take one of two far-apart values by a coin the observation does not show (so chunks planned from fresh noise land
in either mode, and a chunk boundary can jump); snapflow distils it; the boundary is measured on an episode neither
saw. Run from the repository root: ``python scripts/rtc_boundary.py [OUTPUT]``.
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the tests' tiny builders

CHUNK, EXECUTED, DELAY = 8, 4, 2


def main(output: Path) -> None:
    from lerobot.datasets.lerobot_dataset import LeRobotDataset
    from lerobot.policies.factory import make_pre_post_processors
    from torch.utils.data import default_collate

    from snapflow.adapters.lerobot.plugin import SnapFlowSmolVLAPolicy
    from snapflow.benchmark.rtc import boundary_jumps, write_boundary_report
    from snapflow.training.config import TrainConfig
    from snapflow.training.lerobot import distill_lerobot, train_lerobot_teacher
    from snapflow.training.recipes import DistillSettings
    from tests.lerobot_tiny import write_tiny_dataset

    torch.set_num_threads(1)
    work = Path(tempfile.mkdtemp())
    data = write_tiny_dataset(work / "data", episodes=6, frames=24, bimodal=True)
    write_tiny_dataset(work / "held", repo_id="local/held", episodes=1, frames=40, bimodal=True, seed=1)
    teacher = TrainConfig(steps=400, batch_size=16, learning_rate=1e-3, warmup_steps=20, checkpoint_every=10000)
    train_lerobot_teacher("smolvla", data, "local/tiny", work / "teacher", teacher, chunk_size=CHUNK, val_fraction=0.0)
    student = TrainConfig(steps=300, batch_size=16, learning_rate=1e-3, warmup_steps=20, checkpoint_every=10000)
    settings = DistillSettings(consistency_weight=1.0)
    distill_lerobot(str(work / "teacher" / "lerobot_policy"), data, "local/tiny", work / "student", student, settings)
    folder = work / "student" / "lerobot_policy"
    policy = SnapFlowSmolVLAPolicy.from_pretrained(folder)
    preprocessor, _ = make_pre_post_processors(policy.config, pretrained_path=str(folder))
    held = LeRobotDataset("local/held", root=work / "held")
    batch = preprocessor(default_collate([held[index] for index in range(len(held))]))
    rows = boundary_jumps(policy, batch, EXECUTED, DELAY)
    recorded = {
        "policy": "tiny SmolVLA (SmolVLM 64-wide, 2 layers; ~190k parameters), teacher 400 flow-matching steps, "
        "student 300 SnapFlow steps (alpha 0.5, lambda 1)",
        "data": "bimodal tiny LeRobotDataset (tests/lerobot_tiny.py); one held-out episode of 40 frames",
        "chunk_size": CHUNK,
        "executed_per_chunk": EXECUTED,
        "inference_delay": DELAY,
        "execution_horizon": CHUNK - EXECUTED,
        "previous_chunk": "the student's teacher-10 chunk planned executed_per_chunk frames earlier",
        "units": "L2 over the 4 action dimensions, normalised; ms: batch-1 predict_action_chunk, one CPU thread",
    }
    write_boundary_report(rows, recorded, output)
    print((output / "rtc_boundary.md").read_text())


if __name__ == "__main__":
    main(Path(sys.argv[1]) if len(sys.argv) > 1 else Path("docs/results/rtc-boundary-tiny-smolvla"))
