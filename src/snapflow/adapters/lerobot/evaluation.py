"""A LeRobot policy in snapflow's own evaluation (closed loop on a built-in benchmark, offline metrics, latency),
with LeRobot's own pre- and post-processors between the benchmark's raw observations and the adapter: the same
batched evaluator and the same numbers as for a built-in policy."""

from __future__ import annotations

import json
import shutil
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import Tensor, nn

from snapflow.adapters.lerobot.base import LeRobotFlowPolicy, lerobot_observation
from snapflow.adapters.lerobot.checkpoint import (
    PREPROCESSOR_FILE,
    SAFETENSORS_FILE,
    SNAPFLOW_MARKER,
    load_distilled,
    load_pretrained_policy,
    load_student_config,
    marker_of,
    read_marker,
    write_marker,
)
from snapflow.adapters.lerobot.dataset import IMAGE_PREFIX, STATE
from snapflow.adapters.lerobot.local_vlm import bundled_vlm, saved_processors
from snapflow.adapters.lerobot.registry import (
    base_policy_type,
    lerobot_chunk_shape,
    lerobot_own_steps,
    lerobot_time_sampler,
    wrap_policy,
)
from snapflow.adapters.lerobot_types import LEROBOT_POLICY_TYPES
from snapflow.errors import InvalidInputError
from snapflow.flow.modes import NAIVE_1, SNAPFLOW_1
from snapflow.flow.time_sampling import TimeSampler
from snapflow.inference.formats import export_format, export_record
from snapflow.policies.checkpoint import load_export
from snapflow.policies.loaded import BenchSubject, CheckpointError, OpenedPolicy, parameter_count
from snapflow.reporting.files import atomic_write, write_json


class LeRobotProcessor:
    """What the closed-loop evaluator and :class:`~snapflow.data.chunks.ChunkData` use of a processor, for a
    LeRobot policy that reads a state and cameras: raw states, instructions and uint8 images through the policy's
    pre-processor (normalisation, tokenizer); chunks back through its post-processor. Its first camera is the
    benchmark's main one; the others (``observation.images.<name>``) are the benchmark's cameras of those names
    (LIBERO's ``image2``)."""

    def __init__(self, config: Any, preprocessor: Any, postprocessor: Any) -> None:
        cameras = list(config.image_features)
        if not cameras or config.robot_state_feature is None:
            raise InvalidInputError(
                f"snapflow's benchmarks give a state and cameras; this {config.type} reads cameras {cameras} "
                f"and {'a' if config.robot_state_feature else 'no'} state"
            )
        sizes = {config.image_features[camera].shape[-1] for camera in cameras}
        if len(sizes) != 1:
            raise InvalidInputError(f"this {config.type} reads cameras of different sizes {sorted(sizes)}")
        (action,) = config.output_features.values()
        self._chunk_length, width = lerobot_chunk_shape(config)
        if action.shape[0] != width:
            raise InvalidInputError(
                f"this {config.type} pads {action.shape[0]}-D actions to {width}; "
                "snapflow's evaluator needs max_action_dim equal to the action's width"
            )
        self.config, self.preprocessor, self.postprocessor = config, preprocessor, postprocessor
        self.camera, self._extra_cameras = cameras[0], cameras[1:]
        self._unnormalizer = next(step for step in postprocessor.steps if hasattr(step, "_normalize_action"))

    @property
    def chunk_length(self) -> int:
        return self._chunk_length

    @property
    def action_dim(self) -> int:
        return self.config.output_features["action"].shape[0]

    @property
    def state_dim(self) -> int:
        return self.config.robot_state_feature.shape[0]

    @property
    def image_size(self) -> int:
        return self.config.image_features[self.camera].shape[-1]

    @property
    def extra_cameras(self) -> tuple[str, ...]:
        return tuple(camera.removeprefix(IMAGE_PREFIX) for camera in self._extra_cameras)

    def observation(
        self,
        states: np.ndarray,
        instructions: Sequence[str],
        images: np.ndarray | None,
        extra_images: Mapping[str, np.ndarray] | None = None,
    ) -> Any:
        """LeRobot's batch for the model: what its dataset would hold (float state, CHW images in [0, 1], the
        instruction as task) through the policy's pre-processor."""
        extra_images = extra_images or {}
        missing = [name for name in self.extra_cameras if name not in extra_images]
        if images is None or missing:
            raise InvalidInputError(
                f"this {self.config.type} reads cameras {[self.camera, *self._extra_cameras]}; evaluate with images "
                f"rendered{f' (no frames of {missing})' if missing else ''}"
            )

        def chw(frames: np.ndarray) -> Tensor:
            return torch.from_numpy(np.ascontiguousarray(frames)).permute(0, 3, 1, 2).float() / 255

        raw = {
            STATE: torch.as_tensor(np.asarray(states, dtype=np.float32)[:, : self.state_dim]),
            self.camera: chw(images),
            **{IMAGE_PREFIX + name: chw(extra_images[name]) for name in self.extra_cameras},
            "task": list(instructions),
        }
        return self.preprocessor(raw)

    def normalize_actions(self, actions: Tensor) -> Tensor:
        return self._unnormalizer._normalize_action(actions.float(), inverse=False)

    def unnormalize_actions(self, actions: Tensor) -> Tensor:
        return self.postprocessor(actions)


@dataclass
class LoadedLeRobotPolicy(OpenedPolicy):
    """A LeRobot policy folder or hub id opened for snapflow (as :class:`~snapflow.policies.checkpoint.LoadedPolicy`
    is a built-in one): its adapter (or, for an export, the format's runtime), its ``config`` and snapflow's marker
    (``snapflow.json``: distilled or not, held-out share, an export's record under its format's name). Its
    pre- and post-processors, saved beside it, are loaded on first use of :attr:`processor`."""

    policy: LeRobotFlowPolicy | Any
    config: Any
    path: Path
    marker: dict[str, Any]

    @classmethod
    def of_model(cls, model: nn.Module, path: Path, distilled: bool) -> LoadedLeRobotPolicy:
        """LeRobot's policy ``model`` of a declared type, built in memory (random weights at full size, a test's tiny
        one) under its adapter, phi_s included; ``distilled`` says whether its jump modes are SnapFlow's."""
        adapter = model if isinstance(model, LeRobotFlowPolicy) else wrap_policy(model)
        config = adapter.policy.config
        return cls(adapter, config, path, marker_of(config.type, distilled, 0.0))

    @cached_property
    def processor(self) -> LeRobotProcessor:  # type: ignore[override]
        self.config.device = "cpu"
        preprocessor, postprocessor = saved_processors(self.config, self.path, "cpu")
        return LeRobotProcessor(self.config, preprocessor, postprocessor)

    @property
    def policy_type(self) -> str:
        return self.config.type

    @property
    def distilled(self) -> bool:
        # a lerobot-train checkpoint has no snapflow marker: its student config's own label says it
        return bool(self.marker.get("target_time") or getattr(self.config, "distilled", False))

    @property
    def description(self) -> dict[str, Any]:
        return self.marker

    @property
    def distill_command(self) -> str:
        return f"snapflow distill --policy {self.path} ..."

    @property
    def known_prefix_delay(self) -> int:
        """A student's ``distill.rtc_max_delay``, else LeRobot's own ``rtc_training_max_delay`` where it has one."""
        settings = getattr(self.config, "distill", None)
        if settings is not None:
            return settings.rtc_max_delay
        return int(getattr(self.config, "rtc_training_max_delay", 0) or 0)

    @property
    def own_steps(self) -> int:
        return lerobot_own_steps(self.config)

    @property
    def time_sampler(self) -> TimeSampler:
        return lerobot_time_sampler(self.config)

    @property
    def val_fraction(self) -> float:  # type: ignore[override]
        return self.marker.get("val_fraction", 0.0)

    def bench_subject(
        self, name: str, device: torch.device | str = "cpu", dtype: torch.dtype = torch.float32
    ) -> BenchSubject:
        """The adapter's example observation (every camera, the prompt at its full length: the most a prefix costs)
        and fixed noise; an export runs its one jump, on the CPU in float32 as it was traced."""
        declared = LEROBOT_POLICY_TYPES.get(base_policy_type(self.config))
        paper = declared.paper_latency if declared else None
        if self.exported:
            noise = torch.randn(1, *lerobot_chunk_shape(self.config))
            observation = lerobot_observation(self.config, torch.device("cpu"))
            details = {"policy_type": self.config.type, self.export["format"]: self.export}
            only = (SNAPFLOW_1,)
            return BenchSubject(name, self.policy, observation, noise, self.time_sampler, details, SNAPFLOW_1, only)
        device, adapter, config = torch.device(device), self.policy, self.config
        config.device = str(device)
        adapter.to(device)
        if dtype != torch.float32:
            adapter.run_in(dtype)
        adapter.eval()
        details = {
            "parameters": parameter_count(adapter),
            "expert_parameters": parameter_count(nn.ModuleList(adapter.expert_modules())),
            "policy_type": adapter.policy_type,
            "chunk_size": adapter.action_shape[0],
            "tokens": getattr(config, "tokenizer_max_length", None),  # GR00T's prompt has no fixed length
            "cameras": list(config.image_features),
        }
        return BenchSubject(
            name,
            adapter,
            adapter.example_observation(device),
            torch.randn(1, *adapter.action_shape, device=device),
            self.time_sampler,
            details,
            # never distilled (a teacher, or a student type whose config says so): its one step is the naive one
            SNAPFLOW_1 if self.distilled else NAIVE_1,
            dtype=dtype,
            own_steps=type(adapter).own_steps(config),
            paper_latency=paper,
        )

    def export_to(self, output: str | Path, format: str) -> dict[str, Any]:
        """Export this distilled policy to ``output`` in ``format``: its one-step graph over the pre-processed batch,
        beside the folder's config and processors (its weights live in the graph) and a marker with the format's
        record. ``snapflow eval`` opens it again. Returns the record."""
        entry = export_format(format)
        if self.exported:
            raise CheckpointError(f"{self.path} is already an export ({self.export['format']})")
        if not self.distilled:
            raise CheckpointError(
                f"{self.path} is not SnapFlow-distilled: its one step is the naive one; distil it first "
                "(snapflow distill --policy ...) and export the student"
            )
        adapter, output = self.policy.eval(), Path(output)
        if adapter.export_refusal:
            raise InvalidInputError(
                f"snapflow does not export a {adapter.policy_type} student: {adapter.export_refusal}"
            )
        noise = torch.randn(1, *adapter.action_shape, generator=torch.Generator().manual_seed(0))
        observation = adapter.example_observation(torch.device("cpu"))
        output.mkdir(parents=True, exist_ok=True)
        record = {"source": str(self.path), **entry.export(adapter, observation, noise, output)}
        for source in sorted(self.path.iterdir()):
            if source.is_file() and source.name not in {SAFETENSORS_FILE, SNAPFLOW_MARKER, entry.file}:
                atomic_write(output / source.name, lambda target, source=source: shutil.copyfile(source, target))
        vlm = bundled_vlm(self.path)
        if vlm is not None:  # a VLM kept inside, which the copied config names relative to the folder
            shutil.copytree(vlm, output / vlm.relative_to(self.path.resolve()), dirs_exist_ok=True)
        _pad_prompts_to_full_length(output)
        # a lerobot-train checkpoint has no marker of its own: the export's names what it was exported from
        source = {**marker_of(adapter.policy_type, True, self.val_fraction), **self.marker}
        write_marker(output, {**source, format: record})  # last: it makes the export whole
        return record


def load_lerobot_policy(source: str | Path) -> LoadedLeRobotPolicy:
    """A distilled LeRobot policy (phi_s loaded strictly), an export of one, or any LeRobot folder or hub id of a
    declared type, on the CPU."""
    path = Path(source)
    marker = read_marker(path) or {}
    exported = export_record(marker)
    if exported is not None:
        entry, record = exported
        return LoadedLeRobotPolicy(load_export(entry, path / record["file"]), load_student_config(path), path, marker)
    policy = load_distilled(path) if marker.get("target_time") else wrap_policy(load_pretrained_policy(str(source)))
    return LoadedLeRobotPolicy(policy, policy.policy.config, path, marker)


def _pad_prompts_to_full_length(folder: Path) -> None:
    """The graph is traced at the full prompt length (``tokenizer_max_length``): the exported folder's tokenizer pads
    every prompt to it, where LeRobot's may pad to the batch's longest (padding is masked out of the attention)."""
    from snapflow.adapters.lerobot.plugin.processor_snapflow import TOKENIZER_STEP

    config = json.loads((folder / "config.json").read_text())
    if "pad_language_to" in config:
        write_json(folder / "config.json", {**config, "pad_language_to": "max_length"})
    preprocessor = json.loads((folder / PREPROCESSOR_FILE).read_text())
    for step in preprocessor["steps"]:
        if step.get("registry_name") in ("tokenizer_processor", TOKENIZER_STEP):  # LeRobot's, or a kept student's
            step["config"]["padding"] = "max_length"
    write_json(folder / PREPROCESSOR_FILE, preprocessor)


__all__ = [
    "LeRobotProcessor",
    "LoadedLeRobotPolicy",
    "lerobot_observation",
    "load_lerobot_policy",
]
