"""LeRobot policies on a LeRobotDataset with the built-in trainer (Accelerate, safetensors checkpoints, resume):
SnapFlow distillation of any declared LeRobot type, and flow-matching training of a SmolVLA or X-VLA teacher from
scratch (over a SmolVLM of a chosen size written locally). Results are also exported in LeRobot's own layout, with its
processors."""

from __future__ import annotations

from collections.abc import Callable
from contextlib import nullcontext
from pathlib import Path
from typing import Any

import torch

from snapflow._lazy import resolve
from snapflow.adapters.hub import check_source, fetch_hub_file
from snapflow.adapters.lerobot.base import LeRobotFlowPolicy
from snapflow.adapters.lerobot.checkpoint import PREPROCESSOR_FILE, rebuilt_on_cpu, save_distilled, save_teacher
from snapflow.adapters.lerobot.data import ActionChunks, LeRobotChunkData
from snapflow.adapters.lerobot.dataset import policy_features
from snapflow.adapters.lerobot.local_vlm import bundle_vlm, saved_processors
from snapflow.adapters.lerobot.registry import adapter_class, lerobot_time_sampler, wrap_policy
from snapflow.adapters.lerobot.smolvlm import token_budget, words_of, write_smolvlm
from snapflow.adapters.lerobot_config import VIDEO_BACKEND, SmolVLMSize
from snapflow.adapters.lerobot_types import lerobot_policy_type, lerobot_teachers
from snapflow.data.demonstrations import split_episodes
from snapflow.errors import InvalidInputError
from snapflow.objective.base import TwoBranchObjective
from snapflow.objective.settings import DistillSettings
from snapflow.objective.snapflow import SnapFlowObjective
from snapflow.policies.checkpoint import POLICY_WEIGHTS, load_state_strict, read_tensors, resolve_checkpoint
from snapflow.policies.loaded import CheckpointError
from snapflow.reporting.locks import hold_run_lock
from snapflow.reporting.records import as_record
from snapflow.sources import LEROBOT_EXPORT_DIRECTORY, LEROBOT_RUN_FORMAT, open_policy
from snapflow.training.config import VAL_FRACTION, TrainConfig, paper_training
from snapflow.training.trainer import launch_state, train

SMOLVLM_DIRECTORY = "smolvlm"  # the teacher's SmolVLM config and tokenizer, which its exported config points at
DATASET_INFO = "meta/info.json"  # LeRobot's INFO_PATH: the first file of a LeRobotDataset it reads
# the commands named as the holder of a run folder, in another process's refusal
TEACHER_HOLDER = "snapflow train"
DISTILL_HOLDER = "snapflow distill"


def policy_processors(
    policy: torch.nn.Module, policy_path: str, dataset_stats: dict[str, Any], overrides: dict[str, Any] | None = None
) -> tuple[Any, Any]:
    """The teacher's own pre/post-processors (its normalisation statistics and tokenizer) when its folder or hub
    repo carries them; processors built from the dataset's statistics for a local folder that has none."""
    from lerobot.policies.factory import make_pre_post_processors

    local = Path(policy_path)
    if local.is_dir() and not (local / PREPROCESSOR_FILE).is_file():
        return make_pre_post_processors(policy.config, dataset_stats=dataset_stats)
    return saved_processors(policy.config, policy_path, str(policy.config.device), overrides)


def check_dataset(dataset_root: str | Path | None, repo_id: str) -> None:
    """Name a wrong dataset before the policy's weights download (and before LeRobot's dataset modules import,
    seconds), and before the output folder is created."""
    from lerobot.utils.constants import HF_LEROBOT_HOME

    if dataset_root is not None:
        check_source(str(dataset_root), DATASET_INFO, "a LeRobotDataset")
    elif not (HF_LEROBOT_HOME / repo_id / DATASET_INFO).is_file():  # LeRobot reads its own cache first, offline
        fetch_hub_file(repo_id, DATASET_INFO, "a LeRobotDataset", repo_type="dataset")


def check_dataset_features(config: Any, features: dict[str, Any], repo_id: str) -> None:
    """Name every feature the policy needs that the dataset lacks or shapes differently, before any training step
    (LeRobot would pad a longer state or action silently). Images are resized by the policy: only their
    channel count must agree."""
    expected = {**config.input_features, **config.output_features}
    missing = sorted(set(expected) - set(features))
    if missing:
        raise InvalidInputError(f"the dataset {repo_id} lacks the policy's feature(s) {missing}")
    for key, feature in expected.items():
        shape = tuple(features[key]["shape"])
        if feature.type.name == "VISUAL":
            channels = shape[-1] if (features[key].get("names") or [None])[-1] == "channels" else shape[0]
            if channels != feature.shape[0]:
                raise InvalidInputError(
                    f"{key}: the dataset's images have {channels} channels, the policy expects {feature.shape[0]}"
                )
        elif shape != tuple(feature.shape):
            raise InvalidInputError(f"{key}: the dataset has shape {shape}, the policy expects {tuple(feature.shape)}")


def check_finite(dataset: Any, keys: list[str]) -> None:
    """Refuse NaN or inf in the dataset's numeric features (LeRobot records them without complaint), naming the
    feature and the first bad frame, before any training step."""
    import numpy as np

    table = dataset.hf_dataset.with_format("numpy")
    for key in keys:
        values = np.asarray(table[key], dtype=np.float64)
        bad = np.argwhere(~np.isfinite(values.reshape(len(values), -1)))
        if len(bad):
            raise InvalidInputError(
                f"{key} holds NaN or inf (first at frame {int(bad[0][0])}, dimension {int(bad[0][1])})"
            )


def distill_lerobot(
    policy_path: str,
    dataset_root: str | Path | None,
    repo_id: str,
    output: str | Path,
    config: TrainConfig | None = None,
    settings: DistillSettings | None = None,
    resume: bool = False,
    progress: bool = True,
    preprocessor_overrides: dict[str, Any] | None = None,
    val_fraction: float | None = None,
    keep_progress: str | Path | None = None,
    shard: bool = False,
) -> dict[str, Any]:
    """Distill a LeRobot policy of a declared type (hub id or local pretrained directory) on the LeRobotDataset
    ``repo_id`` at ``dataset_root`` (None: LeRobot's cache, fetched from the hub if missing);
    ``preprocessor_overrides`` reach LeRobot's processor loader (e.g. a local tokenizer). ``val_fraction`` of each
    task's episodes is held out (default: what a teacher snapflow trained held out, else none). ``keep_progress`` and
    ``shard``: as :func:`~snapflow.training.trainer.train`'s. ``settings`` are those ``lerobot-train`` takes in a
    student's config (:func:`~snapflow.adapters.lerobot.plugin.configuration_snapflow.check_student_settings` refuses
    the rest), which the exported student's config holds.

    ``output`` is held from loading to export: another process writing it is refused at once with
    :class:`~snapflow.reporting.locks.RunLockedError`."""
    from snapflow.adapters.lerobot.plugin.configuration_snapflow import check_student_settings

    settings = settings or DistillSettings()
    config = config or paper_training()
    check_student_settings(settings)  # what lerobot-train refuses too
    check_dataset(dataset_root, repo_id)
    # held here, not only by `train`, so that the export is inside the hold and a refusal comes before the loading;
    # only the main process of a launch writes, so only it holds the folder (`train` nests inside this hold)
    with hold_run_lock(output, DISTILL_HOLDER) if launch_state().is_main_process else nullcontext():
        return _distill_lerobot(
            policy_path,
            dataset_root,
            repo_id,
            output,
            config,
            settings,
            resume,
            progress,
            preprocessor_overrides,
            val_fraction,
            keep_progress,
            shard,
        )


def training_dataset(metadata: Any, dataset_root: str | Path | None, chunk_size: int, val_fraction: float) -> Any:
    """The LeRobotDataset's training episodes (the last ``val_fraction`` of each task's held out, as for the
    built-in policies: :func:`~snapflow.data.demonstrations.split_episodes`), each frame with its next
    ``chunk_size`` actions as LeRobot's ``delta_timestamps`` give them (:class:`ActionChunks`: an episode's last one
    repeated and marked in ``action_is_pad``)."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    episodes = None
    if val_fraction > 0:
        episodes, _ = split_episodes([entry["tasks"][0] for entry in metadata.episodes], val_fraction)
    dataset = LeRobotDataset(metadata.repo_id, root=dataset_root, episodes=episodes, video_backend=VIDEO_BACKEND)
    return ActionChunks(dataset, chunk_size)


def train_lerobot_teacher(
    policy_type: str,
    dataset_root: str | Path | None,
    repo_id: str,
    output: str | Path,
    config: TrainConfig,
    size: SmolVLMSize | None = None,
    chunk_size: int = 8,
    n_action_steps: int = 4,
    val_fraction: float = VAL_FRACTION,
    resume: bool = False,
    progress: bool = True,
    keep_progress: str | Path | None = None,
) -> dict[str, Any]:
    """LeRobot's policy of ``policy_type`` (one declared ``trains_from_scratch``: SmolVLA, X-VLA) over a VLM at
    ``size``'s widths (default: the tiny one; a SmolVLM config and word tokenizer of the dataset's tasks written to
    ``output/smolvlm``; random weights), every part trained by flow matching (alpha = 1, the policy's own training
    times) on the dataset's state, images and actions, through the adapter, so the loss is the policy's own velocity
    on LeRobot's own pre-processed batches. Exported without phi_s, with its processors and its SmolVLM folder, in
    ``output/lerobot_policy``, ready for ``snapflow distill --policy``. ``keep_progress``: as
    :func:`~snapflow.training.trainer.train`'s."""
    size = size or SmolVLMSize()
    if policy_type not in lerobot_teachers():
        raise InvalidInputError(
            f"snapflow trains LeRobot's {', '.join(lerobot_teachers())} from scratch, not {policy_type!r}"
        )
    adapter_type = adapter_class(policy_type)  # too old a LeRobot is named before the dataset is read
    check_dataset(dataset_root, repo_id)
    with hold_run_lock(output, TEACHER_HOLDER) if launch_state().is_main_process else nullcontext():
        from lerobot.configs.types import FeatureType
        from lerobot.datasets.lerobot_dataset import LeRobotDatasetMetadata
        from lerobot.policies.factory import make_pre_post_processors

        metadata = LeRobotDatasetMetadata(repo_id, root=dataset_root)
        features = policy_features(metadata.features)
        inputs = {key: feature for key, feature in features.items() if feature.type is not FeatureType.ACTION}
        outputs = {key: feature for key, feature in features.items() if feature.type is FeatureType.ACTION}
        if not any(feature.type is FeatureType.VISUAL for feature in inputs.values()):
            raise InvalidInputError(f"the dataset {repo_id} has no camera images; {policy_type} needs at least one")
        tasks = list(metadata.tasks.index)
        vlm = (Path(output) / SMOLVLM_DIRECTORY).resolve()
        if not (vlm / "config.json").is_file():  # a resumed run keeps the tokenizer its checkpoints were trained with
            write_smolvlm(vlm, words_of(tasks), size)
        torch.manual_seed(config.seed)
        sizes = dict(chunk_size=chunk_size, n_action_steps=n_action_steps, tokenizer_max_length=token_budget(tasks))
        policy_class = resolve(lerobot_policy_type(policy_type).policy)
        policy = policy_class(adapter_type.scratch_config(vlm, inputs, outputs, size, **sizes))
        dataset = training_dataset(metadata, dataset_root, chunk_size, val_fraction)
        check_finite(
            dataset.dataset, [key for key, feature in features.items() if feature.type is not FeatureType.VISUAL]
        )
        preprocessor, postprocessor = make_pre_post_processors(policy.config, dataset_stats=metadata.stats)
        adapter = wrap_policy(policy)
        adapter.train_prefix = True
        phi_s = set(adapter.target_time_embedding.parameters())  # stays zero: s = t on every flow-matching row
        run_metadata = {
            "format": LEROBOT_RUN_FORMAT,
            "policy": adapter.policy_type,
            "source": None,
            "dataset": {"repo_id": repo_id, "root": dataset_root and str(dataset_root)},
            "smolvlm": as_record(size),
            "val_fraction": val_fraction,
            "stage": "teacher",
        }
        return _train_and_export(
            adapter,
            SnapFlowObjective(alpha=1.0, time_sampler=lerobot_time_sampler(policy.config)),
            dataset,
            (preprocessor, postprocessor),
            [parameter for parameter in adapter.parameters() if parameter not in phi_s],
            config,
            output,
            TEACHER_HOLDER,
            run_metadata,
            resume,
            progress,
            keep_progress,
            lambda trained, folder: save_teacher(trained, folder, val_fraction),
        )


def _train_and_export(
    adapter: LeRobotFlowPolicy,
    objective: TwoBranchObjective,
    dataset: Any,
    processors: tuple[Any, Any],
    trainable: list[torch.nn.Parameter],
    config: TrainConfig,
    output: str | Path,
    holder: str,
    run_metadata: dict[str, Any],
    resume: bool,
    progress: bool,
    keep_progress: str | Path | None,
    save: Callable[[LeRobotFlowPolicy, Path], Path],
    shard: bool = False,
) -> dict[str, Any]:
    """The one trainer on LeRobot's pre-processed batches of ``dataset`` (``holder``: the command holding
    ``output``), then ``save`` of the result into ``output/lerobot_policy`` with the processors beside it, by the main
    process: the weight average where the run keeps one (``config.ema_decay``), else the trained weights (those of a
    student trained sharded, whole in its last checkpoint, loaded into a copy of it rebuilt on the CPU)."""
    preprocessor, postprocessor = processors
    state = train(
        adapter,
        objective,
        LeRobotChunkData(dataset, preprocessor, adapter),
        None,
        config,
        output,
        run_metadata,
        resume=resume,
        trainable=trainable,
        progress=progress,
        holder=holder,
        keep_progress=keep_progress,
        shard=shard,
    )
    if not launch_state().is_main_process:
        return state
    trained = rebuilt_on_cpu(adapter) if shard else adapter
    if shard or config.ema_decay is not None:  # the policy as the run's last checkpoint holds it
        checkpoint = resolve_checkpoint(output)
        load_state_strict(trained, read_tensors(checkpoint / POLICY_WEIGHTS), checkpoint / POLICY_WEIGHTS)
    export = save(trained, Path(output) / LEROBOT_EXPORT_DIRECTORY)
    preprocessor.save_pretrained(export)
    postprocessor.save_pretrained(export)
    bundle_vlm(export)  # a SmolVLM written locally travels inside the folder: it opens on any machine
    return state


def _distill_lerobot(
    policy_path: str,
    dataset_root: str | Path | None,
    repo_id: str,
    output: str | Path,
    config: TrainConfig,
    settings: DistillSettings,
    resume: bool,
    progress: bool,
    preprocessor_overrides: dict[str, Any] | None,
    val_fraction: float | None,
    keep_progress: str | Path | None,
    shard: bool,
) -> dict[str, Any]:
    """:func:`distill_lerobot` with the output held."""
    from lerobot.datasets.lerobot_dataset import LeRobotDatasetMetadata

    opened = open_policy(policy_path)
    if opened.exported:
        raise CheckpointError(f"{policy_path} is an {opened.export['format']} export: it runs, it does not train")
    adapter, policy = opened.policy, opened.policy.policy
    metadata = LeRobotDatasetMetadata(repo_id, root=dataset_root)
    check_dataset_features(policy.config, metadata.features, repo_id)
    if val_fraction is None:  # the teacher's held-out episodes stay held out
        val_fraction = opened.val_fraction
    dataset = training_dataset(metadata, dataset_root, adapter.action_shape[0], val_fraction)
    features = {**policy.config.input_features, **policy.config.output_features}
    check_finite(dataset.dataset, [key for key, feature in features.items() if feature.type.name != "VISUAL"])
    preprocessor, postprocessor = policy_processors(policy, policy_path, metadata.stats, preprocessor_overrides)
    objective = settings.objective(opened.time_sampler)
    adapter.train_prefix = not settings.freeze_prefix
    run_metadata = {
        "format": LEROBOT_RUN_FORMAT,
        "policy": adapter.policy_type,
        "source": str(policy_path),
        "dataset": {"repo_id": repo_id, "root": dataset_root and str(dataset_root)},
        "distill": as_record(settings),
        "val_fraction": val_fraction,
        "stage": "snapflow",
    }
    return _train_and_export(
        adapter,
        objective,
        dataset,
        (preprocessor, postprocessor),
        adapter.expert_parameters() if settings.freeze_prefix else list(adapter.parameters()),
        config,
        output,
        DISTILL_HOLDER,
        run_metadata,
        resume,
        progress,
        keep_progress,
        lambda trained, folder: save_distilled(trained, folder, val_fraction, settings),
        shard,
    )


__all__ = [
    "SMOLVLM_DIRECTORY",
    "check_dataset",
    "training_dataset",
    "train_lerobot_teacher",
    "check_dataset_features",
    "check_finite",
    "policy_processors",
    "distill_lerobot",
]
