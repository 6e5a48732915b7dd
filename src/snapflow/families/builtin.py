"""snapflow's own policies (``policies/``): trained on demonstrations by snapflow's trainer, kept as checkpoints."""

from __future__ import annotations

from pathlib import Path
from typing import Any, ClassVar

from snapflow.families.base import PolicyFamily, Source, StudentRun, TeacherOptions, TeacherRun
from snapflow.training.config import TrainConfig


class BuiltinFamily(PolicyFamily):
    """The built-in policies: a teacher described by its :class:`~snapflow.policies.configuration.PolicyConfig`."""

    name: ClassVar[str] = "built-in"
    title: ClassVar[str] = "built-in"
    teacher_flag: ClassVar[str] = "teacher"
    data_flag: ClassVar[str] = "data"
    run_key: ClassVar[str] = "policy"
    chooses_teacher_times: ClassVar[bool] = True

    def teacher_types(self) -> tuple[str, ...]:
        from snapflow.policies.factory import POLICIES

        return tuple(POLICIES)

    def architectures(self) -> tuple[str, ...]:
        return self.teacher_types()

    def random_policy(self, architecture: str, device: Any, vlm: str | None = None) -> Any:
        """At its default size on Meta-World MT10's dimensions, unit normalisation, phi_s attached; built on the CPU
        (it is small) and moved where it is timed."""
        from snapflow.envs.metaworld import ACTION_DIM, MT10_INSTRUCTIONS, STATE_DIM
        from snapflow.errors import InvalidInputError
        from snapflow.nn.snapflow_policy import SnapFlowPolicy
        from snapflow.policies.checkpoint import LoadedPolicy, policy_metadata
        from snapflow.policies.factory import default_config, make_model, make_processor, policy_type
        from snapflow.policies.normalization import NormalizationStats

        if vlm is not None:
            raise InvalidInputError(f"--vlm: the built-in {architecture} reads no VLM")
        instructions = list(MT10_INSTRUCTIONS.values())
        config = default_config(architecture, STATE_DIM, ACTION_DIM, instructions)
        state_dim = policy_type(architecture).processor_class.state_entries(config, instructions)
        unit = NormalizationStats([0.0] * state_dim, [1.0] * state_dim, [0.0] * ACTION_DIM, [1.0] * ACTION_DIM)
        processor = make_processor(config, unit, instructions)
        policy = SnapFlowPolicy(make_model(config))
        return LoadedPolicy(policy, processor, policy_metadata(policy, processor), Path(f"<random {architecture}>"))

    def claims_spec(self, spec: Any) -> bool:
        from snapflow.policies.configuration import PolicyConfig

        return isinstance(spec, PolicyConfig)

    def source(self, data: str | None, dataset: str | None, repo_id: str | None) -> Source:
        from snapflow.errors import InvalidInputError

        if not data or dataset:
            raise InvalidInputError(
                f"a built-in policy ({', '.join(self.teacher_types())}) trains on --data, not --dataset"
            )
        return Source(data=Path(data))

    def teacher_spec_for(self, policy_type: str, source: Source, options: TeacherOptions) -> Any:
        """The policy's default configuration for the demonstrations, the options given overriding it."""
        from snapflow.data.demonstrations import Demonstrations
        from snapflow.training.stages import policy_config_for

        options.refuse(self.title, ("smolvlm", "n_action_steps"))
        overrides = dict(options.policy_options or {})
        for name in ("chunk_length", "image_size", "use_image"):
            if getattr(options, name) is not None:
                overrides[name] = getattr(options, name)
        assert source.data is not None
        return policy_config_for(policy_type, Demonstrations.load(source.data), options.state_dim, **overrides)

    def teacher_spec(self, section: str, raw: Any, env: str, tasks: tuple[str, ...]) -> Any:
        """The policy ``type`` (default: the first registered) sized for the benchmark's state and actions, its
        tasks' instructions, the table's other keys its configuration's fields."""
        from snapflow.envs.factory import make_benchmark
        from snapflow.errors import InvalidInputError
        from snapflow.policies.factory import default_config, policy_type
        from snapflow.reporting.settings_tables import checked_table, field_names

        name = raw.get("type", self.teacher_types()[0]) if isinstance(raw, dict) else self.teacher_types()[0]
        try:
            config_class = policy_type(name).config_class
        except (TypeError, ValueError) as error:
            raise InvalidInputError(f"{section}: {error}") from None
        overrides = dict(checked_table(section, raw, {"type"} | field_names(config_class)))
        overrides.pop("type", None)
        benchmark = make_benchmark(env)
        # a policy field that is also a parameter of default_config (a camera policy's state_dim) goes in its place
        state_dim = overrides.pop("state_dim", benchmark.state_dim)
        action_dim = overrides.pop("action_dim", benchmark.action_dim)
        instructions = [benchmark.instruction(task) for task in tasks]
        try:
            return default_config(name, state_dim, action_dim, instructions, **overrides)
        except (TypeError, ValueError) as error:
            raise InvalidInputError(f"{section}: {error}") from None

    def teacher_record(self, spec: Any) -> dict[str, Any]:
        from snapflow.policies.factory import policy_type_of

        return {"policy": {"type": policy_type_of(spec).name, **spec.to_dict()}}

    def train_teacher(self, run: TeacherRun) -> dict[str, Any]:
        from snapflow.training.stages import train_teacher

        progress = run.progress
        return train_teacher(
            run.source.data,
            run.output,
            run.spec,
            run.train,
            run.val_fraction,
            progress.resume,
            progress.progress,
            on_checkpoint=progress.on_checkpoint,
            keep_progress=progress.keep_progress,
        )

    def distill(self, run: StudentRun) -> dict[str, Any]:
        from snapflow.training.stages import distill

        progress = run.progress
        return distill(
            run.teacher,
            run.source.data,
            run.output,
            run.train,
            run.settings,
            run.val_fraction,
            progress.resume,
            progress.progress,
            on_checkpoint=progress.on_checkpoint,
            keep_progress=progress.keep_progress,
            shard=run.shard,
        )

    def policy_path(self, directory: Path, trainer: str = "snapflow") -> Path:
        return directory  # a run folder opens as its latest checkpoint

    def keep_policy(self, directory: Path, trainer: str, kept: Path, stamp: dict[str, Any]) -> None:
        from snapflow.policies.checkpoint import resolve_checkpoint
        from snapflow.training.checkpoint import keep_checkpoint

        keep_checkpoint(resolve_checkpoint(directory), kept, stamp, policy_only=True)

    def restore_policy(self, kept_checkpoint: Path, directory: Path, trainer: str, train: TrainConfig) -> None:
        from snapflow.training.checkpoint import install_checkpoint

        install_checkpoint(kept_checkpoint, directory, train.keep_checkpoints)


__all__ = ["BuiltinFamily"]
