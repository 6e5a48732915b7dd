"""What the built-in training, evaluation and benchmark tests share: tiny policy configurations, short training
settings, demonstrations without a simulator, and Meta-World demonstrations collected once per session.

(A module, not a conftest: the session cache below must be one object whoever asks, from any test folder.)
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from snapflow.data.demonstrations import Demonstrations, Episode
from snapflow.policies.minivla import MiniVLAConfig
from snapflow.training.config import TrainConfig

TINY = MiniVLAConfig(chunk_length=4, prefix_width=32, expert_width=32, num_layers=1, num_heads=2, head_dim=16)
TASK = "drawer-close-v3"
# tasks of the synthetic demonstrations, with Meta-World's state and action sizes (no simulator is run)
SYNTHETIC_TASKS = {"drawer-close-v3": "close the drawer", "reach-v3": "reach the goal position"}
STATE_DIM, ACTION_DIM = 39, 4


def train_config(steps: int, **changes) -> TrainConfig:
    """A few steps at batch 8, logged every step, validated and checkpointed every third."""
    return TrainConfig(
        steps=steps, batch_size=8, warmup_steps=2, log_every=1, validate_every=3, checkpoint_every=3, **changes
    )


def synthetic_demonstrations(
    episodes_per_task: int = 4, length: int = 10, image_size: int | None = None, seed: int = 0
) -> Demonstrations:
    """Episodes of Meta-World's shapes whose actions follow the state (a learnable map), on two tasks."""
    generator = np.random.default_rng(seed)
    states, actions, episodes = [], [], []
    for task in SYNTHETIC_TASKS:
        for variation in range(episodes_per_task):
            episode_states = generator.standard_normal((length, STATE_DIM)).astype(np.float32)
            episode_actions = np.tanh(
                episode_states[:, :ACTION_DIM] + 0.1 * generator.standard_normal((length, ACTION_DIM))
            ).astype(np.float32)
            episodes.append(Episode(task, variation, length * len(episodes), length))
            states.append(episode_states)
            actions.append(episode_actions)
    images = (
        generator.integers(0, 256, (length * len(episodes), image_size, image_size, 3), dtype=np.uint8)
        if image_size
        else None
    )
    episode_index = np.repeat(np.arange(len(episodes)), length)
    return Demonstrations(
        np.concatenate(states),
        np.concatenate(actions),
        episode_index,
        episodes,
        dict(SYNTHETIC_TASKS),
        images,
        "metaworld",
    )


_COLLECTED: dict[tuple, Path] = {}


def collected(
    tmp_path_factory, tasks: tuple[str, ...] = (TASK,), episodes_per_task: int = 4, image_size: int | None = None
) -> Path:
    """Meta-World expert demonstrations (collected once per session for each setting) saved in a folder."""
    key = (tasks, episodes_per_task, image_size)
    if key not in _COLLECTED:
        from snapflow.data.collect import collect
        from snapflow.envs.factory import make_benchmark

        directory = tmp_path_factory.mktemp("demonstrations")
        collect(make_benchmark("metaworld"), list(tasks), episodes_per_task, directory, image_size, progress=False)
        _COLLECTED[key] = directory
    return _COLLECTED[key]
