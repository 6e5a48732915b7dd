"""A closed-loop run's finished waves of episodes on disk, so an interrupted evaluation goes on where it stopped.

One JSON line a wave, appended as the wave ends: its episodes, its wall time and the noise generator's state after
it. A resumed run restores that state and starts at the next wave, so its results equal an uninterrupted run's. The
first line is the run's identity (policy, mode, tasks, seed, ...) and the versions it started under; a file written by
another run is refused, never mixed in, and one started under another simulator version is continued with a warning
naming it. A line cut short by an interruption is dropped on reading. A log may keep a whole copy of itself elsewhere
after each wave (a sweep's, beside its committed records), from which another machine goes on."""

from __future__ import annotations

import base64
import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch

from snapflow.errors import InvalidInputError
from snapflow.evaluation.results import EpisodeResult
from snapflow.reporting.files import write_text
from snapflow.reporting.machine import versions, warn_simulator_differences


@dataclass(frozen=True)
class FinishedWave:
    """One wave's episodes, its wall time and the noise generator's state after it."""

    episodes: list[EpisodeResult]
    seconds: float
    generator_state: torch.Tensor

    def to_dict(self) -> dict[str, Any]:
        state = base64.b64encode(self.generator_state.numpy().tobytes()).decode("ascii")
        return {"episodes": [e.to_dict() for e in self.episodes], "seconds": self.seconds, "generator_state": state}

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> FinishedWave:
        state = torch.frombuffer(bytearray(base64.b64decode(data["generator_state"])), dtype=torch.uint8)
        return cls([EpisodeResult.from_dict(e) for e in data["episodes"]], data["seconds"], state)


class EpisodeLog:
    """The waves of one closed-loop run in ``path``. With ``resume``, the waves already there under the same
    ``identity`` are :attr:`finished` (a file of another identity is a ``ValueError`` naming what differs); without
    it, the file is started anew. With ``kept``, a whole copy of the file is written there (atomically) as it
    starts and after each wave."""

    def __init__(
        self, path: str | Path, identity: dict[str, Any], resume: bool, kept: str | Path | None = None
    ) -> None:
        self.path = Path(path)
        self.kept = None if kept is None else Path(kept)
        self.identity = json.loads(json.dumps(identity))  # as read back: tuples become lists
        self.finished: list[FinishedWave] = []
        if resume and self.path.is_file():
            self.finished = self._read()
        else:
            write_text(self.path, json.dumps({"identity": self.identity, "versions": versions()}) + "\n")
        self._keep()

    def _keep(self) -> None:
        if self.kept is not None:
            write_text(self.kept, self.path.read_text())

    def _read(self) -> list[FinishedWave]:
        lines = self.path.read_text().splitlines()
        try:
            header = json.loads(lines[0]) if lines else {}
            written = header["identity"] if lines else None
        except (json.JSONDecodeError, KeyError, TypeError):
            written = None
        if written is None:
            raise InvalidInputError(f"{self.path} is not an episode log: remove it, or run without --resume")
        differs = sorted(
            key for key in self.identity.keys() | written.keys() if self.identity.get(key) != written.get(key)
        )
        if differs:
            raise InvalidInputError(
                f"{self.path} was written by another evaluation (it differs in {', '.join(differs)}): run without "
                "--resume to start again, or choose another --output"
            )
        warn_simulator_differences(header.get("versions"), f"{self.path}'s finished episodes")
        waves = []
        for number, line in enumerate(lines[1:], start=2):
            try:
                waves.append(FinishedWave.from_dict(json.loads(line)))
            except (json.JSONDecodeError, KeyError, TypeError, ValueError):
                if number < len(lines):  # only the last line may have been cut short
                    raise InvalidInputError(
                        f"{self.path} is corrupt at line {number}: remove it to run again"
                    ) from None
                # drop the cut line, so the next wave appends after a whole one
                write_text(self.path, "\n".join(lines[:-1]) + "\n")
        return waves

    def append(self, wave: FinishedWave) -> None:
        """Record a finished wave, on disk before it returns."""
        with self.path.open("a") as file:
            file.write(json.dumps(wave.to_dict()) + "\n")
            file.flush()
            os.fsync(file.fileno())
        self._keep()


def logged_episodes(folder: str | Path) -> int:
    """How many episodes the episode logs in ``folder`` hold (their whole waves; a line cut short counts none)."""
    count = 0
    for path in Path(folder).glob("*.jsonl") if Path(folder).is_dir() else []:
        for line in path.read_text().splitlines()[1:]:  # the first line is the run's identity
            try:
                count += len(json.loads(line)["episodes"])
            except (json.JSONDecodeError, KeyError, TypeError):
                continue
    return count


__all__ = ["EpisodeLog", "FinishedWave", "logged_episodes"]
