"""LeRobot's flow-matching policies (:mod:`snapflow.adapters.lerobot_types`): trained from scratch or distilled on a
LeRobotDataset, by snapflow's trainer or by LeRobot's own ``lerobot-train``; kept as policy folders with their
processors and local VLM."""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import Any, ClassVar

from snapflow.families.base import PolicyFamily, Source, StudentRun, TeacherOptions, TeacherRun
from snapflow.training.config import TrainConfig

LEROBOT_TRAIN_DIRECTORY = "lerobot-train"  # a lerobot-train student's run, inside its run folder
STUDENT_DIRECTORY = "student"  # the teacher written as its student type, which lerobot-train distils
# the paper's LIBERO setting, in which ``snapflow bench --architecture`` builds a type: two 224-pixel cameras, an 8-D
# state, 7-D actions
LIBERO_CAMERAS = ("observation.images.image", "observation.images.image2")
LIBERO_STATE_DIM, LIBERO_ACTION_DIM = 8, 7


class LeRobotFamily(PolicyFamily):
    """LeRobot's policy types: a teacher described by a :class:`~snapflow.adapters.lerobot_config.LeRobotSpec`."""

    name: ClassVar[str] = "lerobot"
    title: ClassVar[str] = "LeRobot"
    teacher_flag: ClassVar[str] = "policy"
    data_flag: ClassVar[str] = "dataset"
    run_key: ClassVar[str] = "lerobot"
    trainers: ClassVar[tuple[str, ...]] = ("snapflow", "lerobot-train")
    evaluators: ClassVar[tuple[str, ...]] = ("snapflow", "lerobot-eval")
    reads_dataset: ClassVar[bool] = True
    lerobot_recipe: ClassVar[bool] = True
    keeps_own_progress: ClassVar[bool] = True

    def teacher_types(self) -> tuple[str, ...]:
        from snapflow.adapters.lerobot_types import lerobot_teachers

        return tuple(lerobot_teachers())

    def architectures(self) -> tuple[str, ...]:
        """Every declared type (:mod:`snapflow.adapters.lerobot_types`)."""
        from snapflow.adapters.lerobot_types import LEROBOT_POLICY_TYPES

        return tuple(LEROBOT_POLICY_TYPES)

    def random_policy(self, architecture: str, device: Any, vlm: str | None = None) -> Any:
        """In the paper's LIBERO setting (two 224-pixel cameras, 8-D state, 7-D actions), phi_s attached, built where it
        runs (a full-size pi0.5 takes minutes on the CPU, seconds on a GPU). A type that reads a VLM's config and
        processor (its declaration's ``vlm_options``) reads them from ``vlm`` (default: LeRobot's, a hub id); no
        weights are downloaded."""
        import torch
        from huggingface_hub.constants import CONFIG_NAME
        from lerobot.configs.types import FeatureType, PolicyFeature
        from lerobot.policies.factory import get_policy_class, make_policy_config

        from snapflow.adapters.hub import check_source
        from snapflow.adapters.lerobot.evaluation import LoadedLeRobotPolicy
        from snapflow.adapters.lerobot.registry import adapter_class
        from snapflow.adapters.lerobot_types import lerobot_policy_type

        adapter_class(architecture)  # names an unsupported type or too old a LeRobot before a long build
        declared = lerobot_policy_type(architecture)
        features = {
            "input_features": {
                "observation.state": PolicyFeature(type=FeatureType.STATE, shape=(LIBERO_STATE_DIM,)),
                **{camera: PolicyFeature(type=FeatureType.VISUAL, shape=(3, 224, 224)) for camera in LIBERO_CAMERAS},
            },
            "output_features": {"action": PolicyFeature(type=FeatureType.ACTION, shape=(LIBERO_ACTION_DIM,))},
        }
        extra = {**declared.architecture_options, **{option: vlm for option in declared.vlm_options if vlm}}
        config = make_policy_config(architecture, device=str(device), push_to_hub=False, **features, **extra)
        for option in declared.vlm_options:  # named in one line before the build reads the VLM's config and processor
            check_source(getattr(config, option), CONFIG_NAME, f"a VLM for {declared.class_stem}")
        with torch.device(device):
            model = get_policy_class(architecture)(config)
        return LoadedLeRobotPolicy.of_model(model, Path(f"<random {architecture}>"), distilled=True)

    def claims_spec(self, spec: Any) -> bool:
        from snapflow.adapters.lerobot_config import LeRobotSpec

        return isinstance(spec, LeRobotSpec)

    def source(self, data: str | None, dataset: str | None, repo_id: str | None) -> Source:
        """A LeRobotDataset: a root folder on disk (checked here, before LeRobot loads) or a repo id."""
        from snapflow.adapters.hub import dataset_source
        from snapflow.errors import InvalidInputError

        if not dataset or data:
            raise InvalidInputError(
                f"a LeRobot policy ({', '.join(self.teacher_types())}) trains on --dataset (a LeRobotDataset), not --data"
            )
        root, named = dataset_source(dataset, repo_id)
        return Source(dataset=root, repo_id=named)

    def teacher_spec_for(self, policy_type: str, source: Source, options: TeacherOptions) -> Any:
        """LeRobot's policy over a VLM of the size asked for (default: the small one), its frames at that size's own
        or ``image_size``, chunks of ``chunk_length`` (default 8) of which LeRobot runs ``n_action_steps``."""
        from snapflow.adapters.lerobot_config import LeRobotSpec

        options.refuse(self.title, ("state_dim", "use_image", "policy_options"))
        given = {
            "smolvlm": options.smolvlm,
            "image_size": options.image_size,
            "chunk_size": options.chunk_length,
            "n_action_steps": options.n_action_steps,
        }
        return LeRobotSpec(policy_type, **{name: value for name, value in given.items() if value is not None})

    def teacher_spec(self, section: str, raw: Any, env: str, tasks: tuple[str, ...]) -> Any:
        """A type LeRobot trains from scratch here, over a SmolVLM of a known size (the benchmark's shapes are read
        from the LeRobotDataset)."""
        from snapflow.adapters.lerobot_config import SMOLVLM_SIZES, LeRobotSpec
        from snapflow.errors import InvalidInputError
        from snapflow.reporting.settings_tables import checked_count, dataclass_from

        spec = dataclass_from(section, LeRobotSpec(), raw)
        if spec.policy_type not in self.teacher_types():
            raise InvalidInputError(
                f"{section}: policy_type must be one LeRobot trains from scratch here, {list(self.teacher_types())}; "
                f"got {spec.policy_type!r}"
            )
        if spec.smolvlm not in SMOLVLM_SIZES:
            raise InvalidInputError(f"{section}: smolvlm must be one of {list(SMOLVLM_SIZES)}, got {spec.smolvlm!r}")
        for name in ("chunk_size", "n_action_steps", *(("image_size",) if spec.image_size is not None else ())):
            checked_count(section, name, getattr(spec, name))
        return spec

    def teacher_record(self, spec: Any) -> dict[str, Any]:
        from snapflow.reporting.records import as_record

        return {"lerobot": as_record(spec)}

    def train_teacher(self, run: TeacherRun) -> dict[str, Any]:
        from snapflow.training.lerobot import train_lerobot_teacher

        self.check_teacher_training(f"a {run.spec.policy_type} teacher", run.train)
        spec, progress = run.spec, run.progress
        return train_lerobot_teacher(
            spec.policy_type,
            run.source.dataset,
            run.source.repo_id,
            run.output,
            run.train,
            spec.size,
            spec.chunk_size,
            spec.n_action_steps,
            run.val_fraction,
            resume=progress.resume,
            progress=progress.progress,
            keep_progress=progress.keep_progress,
        )

    def distill(self, run: StudentRun) -> dict[str, Any]:
        self.check_trainer(run.trainer)
        if run.trainer == "lerobot-train":
            return self._distill_by_lerobot_train(run)
        from snapflow.training.lerobot import distill_lerobot

        progress = run.progress
        return distill_lerobot(
            run.teacher,
            run.source.dataset,
            run.source.repo_id,
            run.output,
            run.train,
            run.settings,
            progress.resume,
            progress.progress,
            val_fraction=run.val_fraction,
            keep_progress=progress.keep_progress,
            shard=run.shard,
        )

    def _distill_by_lerobot_train(self, run: StudentRun) -> dict[str, Any]:
        """The teacher written as its student type, then ``lerobot-train`` on the training episodes of the
        demonstrations' split (the teacher's held-out ones stay out); it resumes from its own last checkpoint, or
        from the one its progress keeps (each checkpoint kept there as it is saved)."""
        import torch

        from snapflow.data.demonstrations import Demonstrations
        from snapflow.training.config import VAL_FRACTION
        from snapflow.training.lerobot_student import run_lerobot_train, write_student

        student = run.output / STUDENT_DIRECTORY
        if not (student / "config.json").is_file():
            shutil.rmtree(student, ignore_errors=True)
            write_student(run.teacher, student, run.settings)
        training_episodes = None
        if run.source.data is not None:  # the dataset's episodes are the demonstrations' in their order
            held_out = VAL_FRACTION if run.val_fraction is None else run.val_fraction  # every teacher's here
            training_episodes, _ = Demonstrations.load(run.source.data).split(held_out)
        result = run_lerobot_train(
            student,
            run.source.dataset,
            run.source.repo_id,
            run.output / LEROBOT_TRAIN_DIRECTORY,
            run.train,
            training_episodes,
            "cuda" if torch.cuda.is_available() else "cpu",
            torch.get_num_threads(),
            run.progress.keep_progress,
        )
        return {"step": run.train.steps, "wall_time_s": result.wall_time_s}  # its attempts' on every machine

    def policy_path(self, directory: Path, trainer: str = "snapflow") -> Path:
        if trainer == "lerobot-train":
            from snapflow.training.lerobot_student import LAST_CHECKPOINT

            return directory / LEROBOT_TRAIN_DIRECTORY / LAST_CHECKPOINT
        from snapflow.sources import LEROBOT_EXPORT_DIRECTORY

        return directory / LEROBOT_EXPORT_DIRECTORY

    def keep_policy(self, directory: Path, trainer: str, kept: Path, stamp: dict[str, Any]) -> None:
        """The policy folder, its processors and its local VLM inside, which opens on any machine (an unfinished run
        resumes from its trainer's own kept progress instead)."""
        from snapflow.adapters.lerobot.local_vlm import bundle_vlm
        from snapflow.training.checkpoint import keep_checkpoint

        keep_checkpoint(self.policy_path(directory, trainer), kept, stamp, prepare=bundle_vlm)

    def restore_policy(self, kept_checkpoint: Path, directory: Path, trainer: str, train: TrainConfig) -> None:
        from snapflow.training.checkpoint import copy_checkpoint

        copy_checkpoint(kept_checkpoint, self.policy_path(directory, trainer))


__all__ = ["LEROBOT_TRAIN_DIRECTORY", "LeRobotFamily"]
