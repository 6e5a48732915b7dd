"""What a family of policies (built-in, LeRobot) does for the layers above: train a teacher, distil a student, say
where the policy it trained is, and keep it for another machine. The CLI, the sweep's jobs and the benchmark ask a
family (:func:`snapflow.families.family_of`); none of them branches on which one it is."""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

from snapflow.flow.time_distribution import UNIFORM
from snapflow.training.config import TrainConfig
from snapflow.training.recipes import DistillSettings


@dataclass(frozen=True)
class Source:
    """What a run trains on: a built-in policy's demonstrations (``data``), a LeRobot policy's LeRobotDataset at
    ``dataset`` (a folder, or None: LeRobot's cache) named ``repo_id``; a sweep gives both (the dataset is written
    from the demonstrations, whose held-out split ``lerobot-train`` follows)."""

    data: Path | None = None
    dataset: Path | None = None
    repo_id: str | None = None


@dataclass(frozen=True)
class TeacherOptions:
    """What a user asks of a teacher beyond its type (``snapflow train``'s flags); a family reads those it knows and
    refuses, by name, any other that was given. None: not given."""

    chunk_length: int | None = None
    image_size: int | None = None
    state_dim: int | None = None
    use_image: bool | None = None
    smolvlm: str | None = None
    n_action_steps: int | None = None
    policy_options: dict[str, Any] | None = None  # a built-in policy's configuration fields

    def refuse(self, family: str, names: tuple[str, ...]) -> None:
        """Refuse the options of ``names`` that were given: a ``family`` policy has no such option."""
        from snapflow.errors import InvalidInputError

        if given := [name for name in names if getattr(self, name) is not None]:
            raise InvalidInputError(f"a {family} teacher takes no {', '.join(given)}")


@dataclass(frozen=True)
class Progress:
    """How a run goes on after an interruption: ``resume`` its own folder; ``keep_progress`` (a folder the trainer
    copies its latest checkpoint to, to be committed) or ``on_checkpoint`` (called with each one it saves)."""

    resume: bool = False
    progress: bool = True
    keep_progress: Path | None = None
    on_checkpoint: Callable[[Path], None] | None = None


@dataclass(frozen=True)
class TeacherRun:
    """A teacher trained by flow matching from scratch: ``spec`` is the family's own description of the policy (a
    built-in :class:`~snapflow.policies.configuration.PolicyConfig`, a
    :class:`~snapflow.adapters.lerobot_config.LeRobotSpec`), ``output`` its run folder."""

    spec: Any
    source: Source
    output: Path
    train: TrainConfig
    val_fraction: float
    progress: Progress = Progress()


@dataclass(frozen=True)
class StudentRun:
    """A student distilled from the policy at ``teacher`` by ``trainer`` (one of its family's :attr:`trainers`)."""

    teacher: str
    source: Source
    output: Path
    train: TrainConfig
    settings: DistillSettings
    trainer: str = "snapflow"
    val_fraction: float | None = None  # the held-out share (None: what the teacher's run held out, where it says)
    progress: Progress = Progress()
    shard: bool = False  # split over the processes of the launch (snapflow's trainer: training/sharding.py)

    def __post_init__(self) -> None:
        self.train.check_student("a student's training")


class PolicyFamily(ABC):
    """One family of policies: its name, the key a sweep's teacher run names it by, its trainers and evaluators,
    and how it trains, distils, finds and keeps a policy. Heavy imports happen inside the methods."""

    name: ClassVar[str]
    title: ClassVar[str]  # its name in a sentence
    #: the destinations of ``snapflow distill``'s flags that name its teacher and what the student trains on
    teacher_flag: ClassVar[str]
    data_flag: ClassVar[str]
    #: the key of a sweep's teacher run that describes this family's policy (``policy = {...}``, ``lerobot = {...}``)
    run_key: ClassVar[str]
    #: who distils its students: snapflow's trainer first, then any other (LeRobot's ``lerobot-train``)
    trainers: ClassVar[tuple[str, ...]] = ("snapflow",)
    #: who runs a table's episodes of its policies: snapflow's evaluator first, then any other
    evaluators: ClassVar[tuple[str, ...]] = ("snapflow",)
    #: whether it reads a sweep's frames from a LeRobotDataset (kept as video), not from the demonstrations
    reads_dataset: ClassVar[bool] = False
    #: whether its students default to the LeRobot recipe and the paper's LeRobot optimisation
    #: (:func:`snapflow.training.recipes.student_settings`)
    lerobot_recipe: ClassVar[bool] = False
    #: whether its trainers keep a run's progress themselves (``keep_progress``) and resume from it on another
    #: machine; otherwise a sweep keeps each checkpoint, stamped with its job, and puts it back before resuming
    keeps_own_progress: ClassVar[bool] = False
    #: whether its teachers train on the flow-matching time distribution their training names
    #: (``TrainConfig.time_distribution``); otherwise each on its own type's, and a teacher's training names none
    chooses_teacher_times: ClassVar[bool] = False

    @abstractmethod
    def teacher_types(self) -> tuple[str, ...]:
        """The policy types it trains from scratch (``snapflow train --policy-type``, a sweep's teacher run)."""

    @abstractmethod
    def architectures(self) -> tuple[str, ...]:
        """The policy types ``snapflow bench --architecture`` builds at full size with random weights."""

    @abstractmethod
    def random_policy(self, architecture: str, device: Any, vlm: str | None = None) -> Any:
        """Architecture ``architecture`` (one of :meth:`architectures`) at full size with random weights, as an opened
        policy (:class:`~snapflow.policies.loaded.OpenedPolicy`) built on ``device``; ``vlm``: where a type that reads
        a VLM's config reads it."""

    @abstractmethod
    def claims_spec(self, spec: Any) -> bool:
        """Whether ``spec``, a teacher's description, is one of this family's."""

    @abstractmethod
    def source(self, data: str | None, dataset: str | None, repo_id: str | None) -> Source:
        """What ``snapflow train`` or ``distill`` trains on, from its flags: a missing or mistyped input is refused
        in one line naming the flag this family reads."""

    @abstractmethod
    def teacher_spec_for(self, policy_type: str, source: Source, options: TeacherOptions) -> Any:
        """The spec of a ``policy_type`` teacher for ``source`` with ``options`` (``snapflow train``)."""

    @abstractmethod
    def teacher_spec(self, section: str, raw: Any, env: str, tasks: tuple[str, ...]) -> Any:
        """A sweep's teacher-run table ``raw`` (under :attr:`run_key`) read into this family's spec, for ``tasks`` of
        the benchmark ``env``; a mistake is an ``InvalidInputError`` naming ``section``."""

    @abstractmethod
    def teacher_record(self, spec: Any) -> dict[str, Any]:
        """How a teacher's run record names its policy: a cache key of committed records, so never changed."""

    @abstractmethod
    def train_teacher(self, run: TeacherRun) -> dict[str, Any]:
        """Train the teacher; its final training state (``step``, ``wall_time_s``)."""

    @abstractmethod
    def distill(self, run: StudentRun) -> dict[str, Any]:
        """Distil the student; its final training state (``step``, ``wall_time_s``)."""

    @abstractmethod
    def policy_path(self, directory: Path, trainer: str = "snapflow") -> Path:
        """Where a run in ``directory`` (by ``trainer``) leaves the policy that ``open_policy`` opens."""

    @abstractmethod
    def keep_policy(self, directory: Path, trainer: str, kept: Path, stamp: dict[str, Any]) -> None:
        """Keep a finished run's policy in ``kept`` (to be committed) under ``stamp``: what another machine opens."""

    @abstractmethod
    def restore_policy(self, kept_checkpoint: Path, directory: Path, trainer: str, train: TrainConfig) -> None:
        """Put a kept finished policy back where a run in ``directory`` leaves it."""

    def student_settings(
        self, recipe: str | None, train: dict[str, Any], distill: dict[str, Any]
    ) -> tuple[TrainConfig, DistillSettings]:
        """A student's training and distillation settings: the recipe (default: this family's), overridden."""
        from snapflow.training.recipes import student_settings

        return student_settings(recipe, self.lerobot_recipe, train, distill)

    def check_teacher_training(self, where: str, train: TrainConfig) -> None:
        """Refuse a time distribution in the training of a teacher (named by ``where``) of a family whose teachers
        train on their own type's."""
        from snapflow.errors import InvalidInputError

        if train.time_distribution != UNIFORM and not self.chooses_teacher_times:
            raise InvalidInputError(
                f"{where}: a {self.title} teacher trains on its own type's flow-matching times; time_distribution "
                f"{train.time_distribution!r} is a built-in teacher's setting"
            )

    def check_trainer(self, trainer: str) -> None:
        """Refuse a trainer this family's students do not have."""
        from snapflow.errors import InvalidInputError

        if trainer not in self.trainers:
            raise InvalidInputError(
                f"trainer {trainer!r} does not distil a {self.title} policy; its trainers: {list(self.trainers)}"
            )

    def __repr__(self) -> str:
        return f"<{self.name} policy family>"


__all__ = ["PolicyFamily", "Progress", "Source", "StudentRun", "TeacherOptions", "TeacherRun"]
