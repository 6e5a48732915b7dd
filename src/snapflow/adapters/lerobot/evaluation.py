"""A LeRobot policy in snapflow's own evaluation (closed loop on a built-in benchmark, offline metrics, latency),
with LeRobot's own pre- and post-processors between the benchmark's raw observations and the adapter: the same
batched evaluator and the same numbers as for a built-in policy."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import Tensor

from snapflow.adapters.lerobot.base import LeRobotFlowPolicy
from snapflow.adapters.lerobot.checkpoint import load_distilled, read_marker
from snapflow.adapters.lerobot.registry import load_pretrained_policy, wrap_policy
from snapflow.flow.modes import SamplingMode
from snapflow.policies.checkpoint import CheckpointError

STATE = "observation.state"


class LeRobotProcessor:
    """What the closed-loop evaluator and :class:`~snapflow.data.chunks.ChunkData` use of a processor, for a
    LeRobot policy that reads a state and one camera: raw states, instructions and uint8 images through the
    policy's pre-processor (normalisation, tokenizer); chunks back through its post-processor."""

    def __init__(self, config: Any, preprocessor: Any, postprocessor: Any) -> None:
        cameras = list(config.image_features)
        if len(cameras) != 1 or config.robot_state_feature is None:
            raise ValueError(
                f"snapflow's benchmarks give a state and one camera; this {config.type} reads cameras {cameras} "
                f"and {'a' if config.robot_state_feature else 'no'} state"
            )
        (action,) = config.output_features.values()
        if action.shape[0] != config.max_action_dim:
            raise ValueError(
                f"this {config.type} pads {action.shape[0]}-D actions to {config.max_action_dim}; "
                "snapflow's evaluator needs max_action_dim equal to the action's width"
            )
        self.config, self.preprocessor, self.postprocessor = config, preprocessor, postprocessor
        self.camera = cameras[0]
        self._unnormalizer = next(step for step in postprocessor.steps if hasattr(step, "_normalize_action"))

    @property
    def chunk_length(self) -> int:
        return self.config.chunk_size

    @property
    def action_dim(self) -> int:
        return self.config.max_action_dim

    @property
    def state_dim(self) -> int:
        return self.config.robot_state_feature.shape[0]

    @property
    def image_size(self) -> int:
        return self.config.image_features[self.camera].shape[-1]

    def observation(self, states: np.ndarray, instructions: Sequence[str], images: np.ndarray | None) -> Any:
        """LeRobot's batch for the model: what its dataset would hold (float state, CHW images in [0, 1], the
        instruction as task) through the policy's pre-processor."""
        if images is None:
            raise ValueError(f"this {self.config.type} reads camera images; evaluate with images rendered")
        raw = {
            STATE: torch.as_tensor(np.asarray(states, dtype=np.float32)[:, : self.state_dim]),
            self.camera: torch.from_numpy(np.ascontiguousarray(images)).permute(0, 3, 1, 2).float() / 255,
            "task": list(instructions),
        }
        return self.preprocessor(raw)

    def normalize_actions(self, actions: Tensor) -> Tensor:
        return self._unnormalizer._normalize_action(actions.float(), inverse=False)

    def unnormalize_actions(self, actions: Tensor) -> Tensor:
        return self.postprocessor(actions)


@dataclass
class LoadedLeRobotPolicy:
    """A LeRobot policy folder loaded for snapflow's evaluation (as :class:`~snapflow.policies.checkpoint.LoadedPolicy`
    is for a built-in one)."""

    policy: LeRobotFlowPolicy
    processor: LeRobotProcessor
    path: Path
    distilled: bool
    val_fraction: float  # the share of each task's episodes its training held out (0 when unknown)

    def check_mode(self, mode: SamplingMode) -> None:
        """Refuse ``snapflow-N`` on a policy never distilled: its phi_s is zero, so the jump is the naive step."""
        if mode.jump and not self.distilled:
            raise CheckpointError(
                f"{self.path} is not SnapFlow-distilled: {mode.name} would be the naive step under SnapFlow's "
                "name; use teacher-N or naive, or distill it first (snapflow distill --policy ...)"
            )


def load_lerobot_policy(path: str | Path) -> LoadedLeRobotPolicy:
    """A distilled LeRobot policy (phi_s loaded strictly) or any LeRobot SmolVLA / pi0 / pi0.5 folder, with the
    pre- and post-processors saved beside it, on the CPU."""
    from lerobot.policies.factory import make_pre_post_processors

    path = Path(path)
    marker = read_marker(path) or {}
    distilled = bool(marker.get("target_time"))
    adapter = load_distilled(path) if distilled else wrap_policy(load_pretrained_policy(str(path)))
    adapter.policy.config.device = "cpu"
    preprocessor, postprocessor = make_pre_post_processors(
        adapter.policy.config, pretrained_path=str(path), preprocessor_overrides={"device_processor": {"device": "cpu"}}
    )
    processor = LeRobotProcessor(adapter.policy.config, preprocessor, postprocessor)
    return LoadedLeRobotPolicy(adapter, processor, path, distilled, marker.get("val_fraction", 0.0))


__all__ = ["LeRobotProcessor", "LoadedLeRobotPolicy", "load_lerobot_policy"]
