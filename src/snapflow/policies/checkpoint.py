"""A built-in policy on disk: ``policy.safetensors`` (every tensor, no pickle) + ``policy.json`` (the registered
policy's name, configuration, processor statistics and whether phi_s is attached).

A training run keeps such checkpoints under ``checkpoints/step_*`` and names the newest in ``latest.json``
(see :mod:`snapflow.training.checkpoint`); anything that loads a policy accepts either folder.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch
from safetensors import SafetensorError
from safetensors.torch import load_file, save_file
from torch import nn

from snapflow.flow.modes import NAIVE_1, SNAPFLOW_1
from snapflow.flow.time_distribution import UNIFORM, parse_time_distribution
from snapflow.flow.time_sampling import TimeSampler, time_sampler_for
from snapflow.inference.formats import ExportFormat, export_format, export_record
from snapflow.nn.snapflow_policy import SnapFlowPolicy
from snapflow.policies.factory import make_model, make_processor, policy_type, policy_type_of
from snapflow.policies.loaded import BenchSubject, CheckpointError, OpenedPolicy, parameter_count
from snapflow.policies.normalization import NormalizationStats
from snapflow.policies.processor import Processor
from snapflow.protocol import map_tensors
from snapflow.reporting.archive import archived_hint
from snapflow.reporting.files import write_json

POLICY_WEIGHTS, POLICY_CONFIG = "policy.safetensors", "policy.json"
LATEST = "latest.json"
FORMAT = "snapflow-policy"
VERSION = 1


@dataclass
class LoadedPolicy(OpenedPolicy):
    """A built-in checkpoint, or an export of one: its policy (a :class:`SnapFlowPolicy`, or the export's runtime),
    processor and ``policy.json``."""

    policy: Any
    processor: Processor
    metadata: dict[str, Any]
    path: Path

    @property
    def policy_type(self) -> str:
        return self.metadata["policy"]

    @property
    def distilled(self) -> bool:
        return "distill" in self.metadata

    @property
    def description(self) -> dict[str, Any]:
        return self.metadata

    @property
    def known_prefix_delay(self) -> int:
        return int(self.metadata.get("distill", {}).get("rtc_max_delay", 0))

    @property
    def distill_command(self) -> str:
        return f"snapflow distill --teacher {self.path} ..."

    @property
    def time_distribution(self) -> str:
        """The flow-matching time distribution its teacher trained on (a student: its teacher's), as
        :mod:`snapflow.flow.time_distribution` names it; uniform where ``policy.json`` predates the record, as every
        built-in teacher then trained."""
        return self.metadata.get("time_distribution", UNIFORM)

    @property
    def time_sampler(self) -> TimeSampler:
        return time_sampler_for(self.time_distribution)

    @property
    def training_data(self) -> dict[str, Any]:
        return self.metadata.get("data", {})

    @property
    def val_fraction(self) -> float:
        """Share of each task's demonstration episodes the run held out (0.1 where the metadata predates it)."""
        return self.training_data.get("val_fraction", 0.1)

    def bench_subject(
        self, name: str, device: torch.device | str = "cpu", dtype: torch.dtype = torch.float32
    ) -> BenchSubject:
        """Its processor's example observation (a zero state, the first instruction it knows, a black image where it
        reads one) and fixed noise; an export runs its one jump only."""
        torch.manual_seed(0)
        observation = map_tensors(
            self.processor.example_observation(),
            lambda tensor: tensor.to(device=device, dtype=dtype if tensor.is_floating_point() else tensor.dtype),
        )
        noise = torch.randn(1, self.processor.chunk_length, self.processor.action_dim).to(device=device, dtype=dtype)
        policy = self.policy.to(device=device, dtype=dtype).eval()
        details = {"parameters": parameter_count(policy), "policy_type": self.policy_type}
        details["config"] = self.processor.config.to_dict()
        if self.exported:
            details[self.export["format"]] = self.export
        # without phi_s (a teacher checkpoint) the one step is the naive one, timed and named as such
        jumps = self.exported or self.policy.target_time_embedding is not None
        only_modes = (SNAPFLOW_1,) if self.exported else None
        return BenchSubject(
            name,
            policy,
            observation,
            noise,
            self.time_sampler,
            details,
            SNAPFLOW_1 if jumps else NAIVE_1,
            only_modes,
            dtype,
        )

    def export_to(self, output: str | Path, format: str) -> dict[str, Any]:
        """Export this student to ``output`` in ``format``: its one-step graph, and a ``policy.json`` with the
        student's processor and the format's record (source, inputs, versions, the difference to PyTorch measured at
        export) under the format's name. :func:`load_policy` on ``output`` runs it again. Returns the record."""
        entry = export_format(format)
        if self.exported:
            raise CheckpointError(f"{self.path} is already an export ({self.export['format']})")
        if not self.distilled:
            raise CheckpointError(
                f"{self.path} is a flow-matching teacher: its one step is the naive one, and its 10 steps are a loop "
                "an export would unroll; distil it first (snapflow distill --teacher ...) and export the student"
            )
        output = Path(output)
        output.mkdir(parents=True, exist_ok=True)
        observation = self.processor.example_observation()
        noise = torch.randn(
            1, self.processor.chunk_length, self.processor.action_dim, generator=torch.Generator().manual_seed(0)
        )
        record = {"source": str(self.path), **entry.export(self.policy.eval(), observation, noise, output)}
        write_json(output / POLICY_CONFIG, {**self.metadata, format: record})  # last: it makes the folder a checkpoint
        return record


def policy_metadata(policy: SnapFlowPolicy, processor: Processor, **extra: Any) -> dict[str, Any]:
    """What ``policy.json`` records of a built-in policy, plus ``extra`` (stage, data, settings)."""
    return {
        "format": FORMAT,
        "version": VERSION,
        "policy": policy_type_of(processor.config).name,
        "config": processor.config.to_dict(),
        "target_time": policy.target_time_embedding is not None,
        "stats": vars(processor.stats),
        "instructions": list(processor.instructions),
        **extra,
    }


def read_json(path: Path) -> dict[str, Any]:
    if not path.is_file():
        raise CheckpointError(f"{path} not found")
    try:
        return json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as error:
        raise CheckpointError(f"{path} is corrupt (not JSON: {error})") from None


def read_tensors(path: Path) -> dict[str, torch.Tensor]:
    if not path.is_file():
        raise CheckpointError(f"{path} not found{archived_hint(path)}")
    try:
        return load_file(path)
    except (SafetensorError, OSError, ValueError, RuntimeError) as error:
        raise CheckpointError(f"{path} is corrupt or not a safetensors file ({error})") from None


def _with_tied_names(module: nn.Module, tensors: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    """``tensors`` plus every name of a tensor the module ties to one of them (a shared embedding, saved once by
    ``safetensors.torch.save_model``), read from the saved one."""
    names_of: dict[int, list[str]] = {}
    for name, tensor in module.state_dict(keep_vars=True).items():
        names_of.setdefault(id(tensor), []).append(name)
    filled = dict(tensors)
    for names in names_of.values():
        saved = next((name for name in names if name in tensors), None)
        if saved is not None:
            filled.update({name: tensors[saved] for name in names if name not in tensors})
    return filled


def load_state_strict(module: nn.Module, tensors: dict[str, torch.Tensor], source: Path) -> None:
    """Load weights, naming every missing, unexpected or differently shaped tensor (a tied one is saved once)."""
    tensors = _with_tied_names(module, tensors)
    expected = module.state_dict()
    missing = sorted(set(expected) - set(tensors))
    unexpected = sorted(set(tensors) - set(expected))
    shapes = [
        f"{k}: checkpoint {tuple(tensors[k].shape)} vs model {tuple(v.shape)}"
        for k, v in expected.items()
        if k in tensors and tensors[k].shape != v.shape
    ]
    if missing or unexpected or shapes:
        details = "; ".join(
            filter(
                None,
                [
                    f"missing {missing[:5]}{'...' if len(missing) > 5 else ''}" if missing else "",
                    f"unexpected {unexpected[:5]}{'...' if len(unexpected) > 5 else ''}" if unexpected else "",
                    f"shape mismatch {shapes[:5]}" if shapes else "",
                ],
            )
        )
        raise CheckpointError(f"{source} does not match the policy: {details}")
    module.load_state_dict(tensors, strict=True)


def untied_names(module: nn.Module) -> list[str]:
    """The names of ``module``'s state, each tensor once: a tensor the module ties under several names (a shared
    embedding) under its first, as :func:`load_state_strict` reads it back."""
    first = {}
    for name, tensor in module.state_dict(keep_vars=True).items():
        first.setdefault(id(tensor), name)
    return list(first.values())


def untied_state(module: nn.Module) -> dict[str, torch.Tensor]:
    """``module``'s tensors for a safetensors file, each once (:func:`untied_names`)."""
    state = module.state_dict(keep_vars=True)
    return {name: state[name].detach().cpu().contiguous() for name in untied_names(module)}


def write_policy(directory: Path, policy: nn.Module, metadata: dict[str, Any]) -> None:
    """``policy.safetensors`` and ``policy.json`` into ``directory`` (callers make the folder appear atomically)."""
    write_weights(directory, untied_state(policy), metadata)


def write_weights(directory: Path, weights: dict[str, torch.Tensor], metadata: dict[str, Any]) -> None:
    """:func:`write_policy` of a policy's :func:`untied_state` (or a sharded one's, gathered)."""
    save_file(weights, directory / POLICY_WEIGHTS)
    write_json(directory / POLICY_CONFIG, metadata)


def is_builtin_checkpoint(path: str | Path) -> bool:
    """Whether ``path`` is what :func:`resolve_checkpoint` accepts: a checkpoint directory or a run directory."""
    return (Path(path) / POLICY_CONFIG).is_file() or (Path(path) / LATEST).is_file()


def resolve_checkpoint(path: str | Path) -> Path:
    """A checkpoint directory, or a run directory whose ``latest.json`` names one."""
    path = Path(path)
    if (path / POLICY_CONFIG).is_file():
        return path
    if (path / LATEST).is_file():
        return path / read_json(path / LATEST)["checkpoint"]
    if not path.exists():
        raise CheckpointError(f"{path} does not exist")
    raise CheckpointError(f"{path} holds neither a checkpoint ({POLICY_CONFIG}) nor a run ({LATEST})")


def load_policy(path: str | Path, target_time: bool | None = None) -> LoadedPolicy:
    """Build the registered policy a checkpoint describes and load its weights.

    ``target_time=True`` on a checkpoint saved without phi_s (a teacher) adds a fresh, zero-initialised
    one: that is how distillation starts from the teacher.
    """
    directory = resolve_checkpoint(path)
    metadata = read_json(directory / POLICY_CONFIG)
    if metadata.get("format") != FORMAT:
        raise CheckpointError(
            f"{directory / POLICY_CONFIG} is not a snapflow policy (format {metadata.get('format')!r})"
        )
    for field in ("policy", "config", "stats", "target_time"):
        if field not in metadata:
            raise CheckpointError(f"{directory / POLICY_CONFIG} lacks the field {field!r}")
    try:
        entry = policy_type(metadata["policy"])
    except ValueError as error:
        raise CheckpointError(f"{directory / POLICY_CONFIG}: {error}") from None
    try:
        config = entry.config_class.from_dict(metadata["config"])
        processor = make_processor(config, NormalizationStats(**metadata["stats"]), metadata.get("instructions", ()))
        parse_time_distribution(metadata.get("time_distribution", UNIFORM))
    except (TypeError, ValueError) as error:
        raise CheckpointError(f"{directory / POLICY_CONFIG}: invalid field: {error}") from None
    exported = export_record(metadata)
    if exported is not None:
        entry, record = exported
        if target_time:
            raise CheckpointError(f"{directory} is an {entry.name} export: it runs, it does not train; use its source")
        return LoadedPolicy(load_export(entry, directory / record["file"]), processor, metadata, directory)
    saved_target_time = bool(metadata["target_time"])
    policy = SnapFlowPolicy(make_model(config), target_time=saved_target_time)
    load_state_strict(policy, read_tensors(directory / POLICY_WEIGHTS), directory / POLICY_WEIGHTS)
    if target_time and not saved_target_time:
        policy = SnapFlowPolicy(policy.model, target_time=True)
    elif target_time is False and saved_target_time:
        raise CheckpointError(
            f"{directory} is a SnapFlow student; it cannot be loaded without its target-time embedding"
        )
    return LoadedPolicy(policy, processor, metadata, directory)


def load_export(entry: ExportFormat, path: Path) -> Any:
    """An exported one-step file in its runtime, or a named error for a missing or corrupt file."""
    if not path.is_file():
        raise CheckpointError(f"{path} not found")
    try:
        return entry.load(path)
    except Exception as error:  # runtimes raise their own exception types for a truncated or foreign file
        raise CheckpointError(f"{path} is corrupt or not an {entry.name} graph ({str(error).strip()[:200]})") from None


__all__ = [
    "load_export",
    "is_builtin_checkpoint",
    "CheckpointError",
    "LoadedPolicy",
    "LATEST",
    "POLICY_CONFIG",
    "POLICY_WEIGHTS",
    "load_policy",
    "load_state_strict",
    "policy_metadata",
    "read_json",
    "read_tensors",
    "resolve_checkpoint",
    "write_policy",
    "write_weights",
    "untied_names",
]
