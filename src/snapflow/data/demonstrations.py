"""Demonstrations on disk: ``demonstrations.npz`` (arrays) + one ``.npy`` file per camera + ``meta.json`` (schema,
episodes, statistics).

``demonstrations.npz``:
    states         float32 (N, state_dim)     observation state at each step
    actions        float32 (N, action_dim)    action taken at that step
    episode_index  int64   (N,)               which episode each step belongs to (episodes are contiguous)
``images.npy``         uint8 (N, H, W, 3)     optional camera frames (the benchmark's main camera)
``images.<name>.npy``  uint8 (N, H, W, 3)     the frames of each of its other cameras (LIBERO's wrist camera)
``meta.json``: ``format``, ``version``, ``env`` (the benchmark's registered name), ``state_dim``, ``action_dim``,
``episodes`` (task, variation, start, length), ``instructions`` (task -> text) and ``stats`` (mean / std of states
and actions).

Frames are stored uncompressed and loaded memory-mapped: a LIBERO suite's 128-px frames of two cameras are ~6 GB,
which training and evaluation processes then read a batch at a time and share through the page cache instead of
each decompressing a copy. Version 1 kept the frames inside the npz; it still loads.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field, fields, replace
from pathlib import Path
from typing import Any

import numpy as np

from snapflow.envs.factory import DEFAULT_BENCHMARK
from snapflow.errors import InvalidInputError
from snapflow.policies.normalization import NormalizationStats
from snapflow.reporting.files import atomic_write, write_json

FORMAT = "snapflow-demonstrations"
VERSION = 2
READABLE_VERSIONS = (1, 2)
ARRAYS_FILE = "demonstrations.npz"
META_FILE = "meta.json"
IMAGES = "images"  # the main camera's frames: images.npy; another camera's: images.<camera>.npy


@dataclass(frozen=True)
class Episode:
    task: str
    variation: int
    start: int
    length: int


class DemonstrationError(InvalidInputError):
    """A demonstration set that cannot be used, with the reason."""


@dataclass
class Demonstrations:
    states: np.ndarray
    actions: np.ndarray
    episode_index: np.ndarray
    episodes: list[Episode]
    instructions: dict[str, str]
    images: np.ndarray | None = None
    env: str = DEFAULT_BENCHMARK
    extra_images: dict[str, np.ndarray] = field(default_factory=dict)  # other cameras' frames, by camera name
    # the noise on the executed actions they were collected with (DART; the actions held are the experts' own)
    action_noise: float = 0.0
    noise_seed: int = 0  # the seed of that noise, beside each (task, variation)'s own (collect.noise_generator)
    first_variation: int = 0  # the training variation (reset) each task's collection started from

    def __post_init__(self) -> None:
        self.validate()

    @property
    def tasks(self) -> list[str]:
        return list(dict.fromkeys(episode.task for episode in self.episodes))

    def validate(self) -> None:
        """Reject what would silently corrupt training: bad shapes, dtypes, non-finite values, empty episodes."""
        if self.states.ndim != 2 or self.actions.ndim != 2 or len(self.states) != len(self.actions):
            raise DemonstrationError(
                f"states {self.states.shape} and actions {self.actions.shape} must be (N, dim) with one N"
            )
        for name in ("states", "actions"):
            array = getattr(self, name)
            if not np.issubdtype(array.dtype, np.floating):
                raise DemonstrationError(f"{name} must be floating point, got {array.dtype}")
            if not np.isfinite(array).all():
                bad = np.argwhere(~np.isfinite(array))[0]
                raise DemonstrationError(f"{name} contains NaN or inf (first at step {bad[0]}, dimension {bad[1]})")
        if not self.episodes:
            raise DemonstrationError("no episodes")
        position = 0
        for number, episode in enumerate(self.episodes):
            if episode.length < 1:
                raise DemonstrationError(f"episode {number} ({episode.task}) is empty")
            if episode.start != position:
                raise DemonstrationError(f"episode {number} starts at {episode.start}, expected {position}")
            if episode.task not in self.instructions:
                raise DemonstrationError(f"episode {number}: task {episode.task!r} has no instruction")
            position += episode.length
        if position != len(self.states) or len(self.episode_index) != position:
            raise DemonstrationError(f"episodes cover {position} steps but the arrays hold {len(self.states)}")
        if self.extra_images and self.images is None:
            raise DemonstrationError("frames of other cameras without the main camera's")
        for name, images in {"images": self.images, **{f"images.{k}": v for k, v in self.extra_images.items()}}.items():
            if images is not None and (images.shape[0] != position or images.dtype != np.uint8 or images.ndim != 4):
                raise DemonstrationError(
                    f"{name} must be uint8 (N, H, W, 3) with N = {position}, got {images.dtype} {images.shape}"
                )

    def stats(self, episodes: list[int] | None = None, state_dim: int | None = None) -> NormalizationStats:
        """Normalisation of the given episodes (default all); ``state_dim``: of the leading state entries only."""
        rows = self.rows(episodes) if episodes is not None else slice(None)
        return NormalizationStats.from_arrays(self.states[rows, :state_dim], self.actions[rows])

    def rows(self, episodes: list[int]) -> np.ndarray:
        """The steps of the given episodes, in the order given."""
        ranges = [np.arange(self.episodes[e].start, self.episodes[e].start + self.episodes[e].length) for e in episodes]
        return np.concatenate(ranges) if ranges else np.zeros(0, dtype=np.int64)

    def select(self, episodes: list[int]) -> Demonstrations:
        """The given episodes alone, in the order given, with their frames."""
        rows = self.rows(episodes)
        chosen, start = [], 0
        for e in episodes:
            chosen.append(replace(self.episodes[e], start=start))
            start += self.episodes[e].length
        return replace(
            self,
            states=self.states[rows],
            actions=self.actions[rows],
            episode_index=np.repeat(np.arange(len(episodes)), [episode.length for episode in chosen]),
            episodes=chosen,
            images=None if self.images is None else self.images[rows],
            extra_images={name: frames[rows] for name, frames in self.extra_images.items()},
        )

    def split(self, val_fraction: float) -> tuple[list[int], list[int]]:
        """Hold out the last ``val_fraction`` of each task's episodes (:func:`split_episodes`)."""
        return split_episodes([episode.task for episode in self.episodes], val_fraction)

    def save(self, directory: str | Path) -> Path:
        directory = Path(directory)
        cameras = {IMAGES: self.images} if self.images is not None else {}
        cameras.update({f"{IMAGES}.{name}": frames for name, frames in self.extra_images.items()})
        for name, frames in cameras.items():
            atomic_write(directory / f"{name}.npy", lambda path, frames=frames: np.save(path, frames))
        arrays = {"states": self.states, "actions": self.actions, "episode_index": self.episode_index}
        atomic_write(directory / ARRAYS_FILE, lambda path: np.savez_compressed(open(path, "wb"), **arrays))
        write_json(  # last: a folder without it holds no demonstrations yet
            directory / META_FILE,
            {
                "format": FORMAT,
                "version": VERSION,
                "env": self.env,
                "state_dim": int(self.states.shape[1]),
                "action_dim": int(self.actions.shape[1]),
                "num_steps": int(len(self.states)),
                "has_images": self.images is not None,
                "extra_cameras": list(self.extra_images),
                "action_noise": self.action_noise,
                "noise_seed": self.noise_seed,
                "first_variation": self.first_variation,
                "instructions": self.instructions,
                "episodes": [asdict(e) for e in self.episodes],
                "stats": asdict(self.stats()),
            },
        )
        return directory

    @classmethod
    def concatenate(cls, parts: list[Demonstrations]) -> Demonstrations:
        """One set of the parts' episodes in order (each part, say, one task's); they must share benchmark and cameras."""
        if not parts:
            raise DemonstrationError("nothing to concatenate")
        first = parts[0]
        for part in parts[1:]:
            if part.env != first.env or list(part.extra_images) != list(first.extra_images):
                raise DemonstrationError(
                    f"parts differ in benchmark or cameras: {first.env} {list(first.extra_images)} and "
                    f"{part.env} {list(part.extra_images)}"
                )
            if (part.images is None) != (first.images is None):
                raise DemonstrationError("some parts hold camera frames and others do not")
            collected, other = (
                (part.action_noise, part.noise_seed, part.first_variation),
                (first.action_noise, first.noise_seed, first.first_variation),
            )
            if collected != other:
                raise DemonstrationError(
                    f"parts were collected differently (action noise, its seed, first variation): {other} and "
                    f"{collected}"
                )
        episodes, offset = [], 0
        for part in parts:
            episodes += [replace(episode, start=episode.start + offset) for episode in part.episodes]
            offset += len(part.states)
        counts = np.cumsum([0] + [len(part.episodes) for part in parts[:-1]])
        return cls(
            np.concatenate([part.states for part in parts]),
            np.concatenate([part.actions for part in parts]),
            np.concatenate([part.episode_index + count for part, count in zip(parts, counts, strict=True)]),
            episodes,
            {task: text for part in parts for task, text in part.instructions.items()},
            np.concatenate([part.images for part in parts]) if first.images is not None else None,
            first.env,
            {name: np.concatenate([part.extra_images[name] for part in parts]) for name in first.extra_images},
            first.action_noise,
            first.noise_seed,
            first.first_variation,
        )

    @classmethod
    def load(cls, directory: str | Path) -> Demonstrations:
        directory = Path(directory)
        meta_path, arrays_path = directory / META_FILE, directory / ARRAYS_FILE
        for path in (meta_path, arrays_path):
            if not path.is_file():
                raise DemonstrationError(f"{path} not found; run `snapflow collect --output {directory}` first")
        try:
            meta = json.loads(meta_path.read_text())
        except json.JSONDecodeError as error:
            raise DemonstrationError(f"{meta_path} is not valid JSON: {error}") from None
        if meta.get("format") != FORMAT or meta.get("version") not in READABLE_VERSIONS:
            raise DemonstrationError(
                f"{meta_path}: expected format {FORMAT!r} version {VERSION}, got {meta.get('format')!r} {meta.get('version')!r}"
            )
        missing = [key for key in ("episodes", "instructions") if key not in meta]
        if missing:
            raise DemonstrationError(f"{meta_path} lacks {missing}")
        try:
            with np.load(arrays_path, allow_pickle=False) as arrays:
                loaded = {key: arrays[key] for key in arrays.files}
        except (OSError, ValueError) as error:
            raise DemonstrationError(f"{arrays_path} cannot be read: {error}") from None
        missing = [key for key in ("states", "actions", "episode_index") if key not in loaded]
        if missing:
            raise DemonstrationError(f"{arrays_path} lacks arrays {missing}")
        for path in sorted(directory.glob(f"{IMAGES}*.npy")):
            try:
                loaded[path.stem] = np.load(path, mmap_mode="r", allow_pickle=False)
            except (OSError, ValueError) as error:
                raise DemonstrationError(f"{path} cannot be read: {error}") from None
        return cls(
            loaded["states"],
            loaded["actions"],
            loaded["episode_index"],
            _episodes(meta["episodes"], meta_path),
            _instructions(meta["instructions"], meta_path),
            loaded.get(IMAGES),
            _env(meta.get("env", DEFAULT_BENCHMARK), meta_path),
            {key.removeprefix(f"{IMAGES}."): array for key, array in loaded.items() if key.startswith(f"{IMAGES}.")},
            _action_noise(meta.get("action_noise", 0.0), meta_path),  # absent: collected before noise existed
            # absent: collected before they could be chosen
            _count(meta.get("noise_seed", 0), "noise_seed", meta_path),
            _count(meta.get("first_variation", 0), "first_variation", meta_path),
        )


def split_episodes(episode_tasks: list[str], val_fraction: float) -> tuple[list[int], list[int]]:
    """(training, held-out) episode indices: the last ``val_fraction`` of each task's episodes held out (at least
    one when a task has two), given each episode's task in order; the one rule for every dataset format."""
    if not 0 <= val_fraction < 1:
        raise InvalidInputError(f"the validation fraction must be in [0, 1), got {val_fraction}")
    train, val = [], []
    for task in dict.fromkeys(episode_tasks):
        ids = [i for i, episode_task in enumerate(episode_tasks) if episode_task == task]
        held_out = min(max(round(val_fraction * len(ids)), 1 if val_fraction > 0 and len(ids) > 1 else 0), len(ids) - 1)
        train += ids[: len(ids) - held_out]
        val += ids[len(ids) - held_out :]
    return train, val


def _episodes(entries: Any, source: Path) -> list[Episode]:
    """Episode records from ``meta.json``, each checked field by field."""
    types = {field.name: field.type for field in fields(Episode)}
    if not isinstance(entries, list):
        raise DemonstrationError(f"{source}: 'episodes' must be a list, got {type(entries).__name__}")
    episodes = []
    for number, entry in enumerate(entries):
        if not isinstance(entry, dict) or set(entry) != set(types):
            raise DemonstrationError(
                f"{source}: episode {number} must have exactly the fields {sorted(types)}, got {entry!r}"
            )
        for name, kind in types.items():
            expected = {"str": str, "int": int}[kind]
            if not isinstance(entry[name], expected) or isinstance(entry[name], bool):
                raise DemonstrationError(
                    f"{source}: episode {number} field {name!r} must be {kind}, got {entry[name]!r}"
                )
        episodes.append(Episode(**entry))
    return episodes


def _env(name: Any, source: Path) -> str:
    if not isinstance(name, str):
        raise DemonstrationError(f"{source}: 'env' must name a benchmark, got {name!r}")
    return name


def check_action_noise(value: Any) -> float:
    """A collection's action noise (the standard deviation added to the executed actions) as a float: a number of at
    least 0, never a bool or NaN; a ``ValueError`` otherwise."""
    if isinstance(value, bool) or not isinstance(value, int | float) or not value >= 0:
        raise InvalidInputError(f"action_noise must be a number of at least 0, got {value!r}")
    return float(value)


def _count(value: Any, name: str, source: Path) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < 0:
        raise DemonstrationError(f"{source}: {name} must be an integer of at least 0, got {value!r}")
    return value


def _action_noise(value: Any, source: Path) -> float:
    try:
        return check_action_noise(value)
    except ValueError as error:
        raise DemonstrationError(f"{source}: {error}") from None


def _instructions(instructions: Any, source: Path) -> dict[str, str]:
    if not isinstance(instructions, dict) or not all(
        isinstance(k, str) and isinstance(v, str) for k, v in instructions.items()
    ):
        raise DemonstrationError(f"{source}: 'instructions' must map task names to instruction strings")
    return instructions


__all__ = [
    "Demonstrations",
    "DemonstrationError",
    "Episode",
    "split_episodes",
    "check_action_noise",
    "FORMAT",
    "VERSION",
    "ARRAYS_FILE",
    "META_FILE",
]
