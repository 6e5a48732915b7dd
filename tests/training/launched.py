"""What each process of a test's ``accelerate launch`` runs (tests/training/test_data_parallel.py): ``snapflow`` or
``lerobot-train`` with its arguments, watched and, if asked, killed.

    launched.py RECORD RUN_FOLDER KILL_AT PROBE COMMAND ARGUMENT...

Every process notes each file it creates, writes, renames or removes under RUN_FOLDER, and writes the list to
``RECORD-<rank>.json`` as it exits. KILL_AT > 0: the main process SIGKILLs itself once the checkpoint of that step is
whole and marked latest (the launcher then stops the others), as a run is killed at any moment. PROBE ``targets``: each
process also writes, beside its record, every state of consistency distillation's target network and the weights it
was moved towards (``RECORD-<rank>-targets.pt``). PROBE ``loader-generator``: every DataLoader draws its iterators' base
seed from a generator of its own, not from the global RNG: lerobot-train (0.6.1) restores the RNG state of its
checkpoint before it makes the DataLoader's iterator, whose base seed takes one draw of the global RNG, so that the
noise of a resumed run is one draw off an unbroken run's; this puts the draws back in step. PROBE ``tiny-pi05``:
LeRobot's pi0.5 builds and loads at the tests' tiny size in this process (:func:`tests.lerobot_tiny.tiny_pi_configs`).
"""

from __future__ import annotations

import atexit
import contextlib
import json
import os
import signal
import sys
from pathlib import Path

WRITING = os.O_WRONLY | os.O_RDWR | os.O_CREAT | os.O_APPEND | os.O_TRUNC
CHANGING = {"os.mkdir", "os.rename", "os.remove", "os.rmdir", "shutil.rmtree", "os.symlink", "os.link", "os.truncate"}


def watch_writes(run: Path, record: Path, rank: int) -> None:
    """Note every path under ``run`` (not ``run`` itself: a probe of whether it is writable) this process changes."""
    writes: list[str] = []

    def audit(event: str, arguments: tuple) -> None:
        if event == "open":
            paths = [arguments[0]] if isinstance(arguments[2], int) and arguments[2] & WRITING else []
        elif event in CHANGING:
            paths = arguments[:2] if event in ("os.rename", "os.symlink", "os.link") else arguments[:1]
        else:
            return
        for path in paths:
            if isinstance(path, (str, os.PathLike)):
                absolute = Path(os.path.abspath(path))
                if absolute != run and absolute.is_relative_to(run):
                    writes.append(f"{event} {absolute.relative_to(run)}")

    def write_record() -> None:
        # whole or absent: the launcher may kill this process while it writes (its reader once saw an empty file)
        partial = Path(f"{record}-{rank}.json.partial")
        partial.write_text(json.dumps(writes))
        os.replace(partial, f"{record}-{rank}.json")

    sys.addaudithook(audit)
    atexit.register(write_record)


def kill_after_checkpoint(command: str, step: int) -> None:
    """SIGKILL the main process once the checkpoint of ``step`` is whole and marked latest."""
    if command == "lerobot-train":
        from lerobot.scripts import lerobot_train

        mark = lerobot_train.update_last_checkpoint

        def mark_then_die(checkpoint_dir):
            marked = mark(checkpoint_dir)
            if int(Path(checkpoint_dir).name) == step:
                os.kill(os.getpid(), signal.SIGKILL)
            return marked

        lerobot_train.update_last_checkpoint = mark_then_die
        return
    from snapflow.training import trainer

    save = trainer.save_run_checkpoint

    def save_then_die(accelerator, module, optimizer, average, state, done, *rest):
        path = save(accelerator, module, optimizer, average, state, done, *rest)
        if done == step and accelerator.is_main_process:
            os.kill(os.getpid(), signal.SIGKILL)
        return path

    trainer.save_run_checkpoint = save_then_die


def probe_targets(record: Path, rank: int) -> None:
    """Keep every state of consistency distillation's target network and the weights it moved towards."""
    import torch

    from snapflow.objective.consistency_distillation import ConsistencyDistillationObjective

    target_network = ConsistencyDistillationObjective._target_network
    calls: list[dict] = []

    def flat(module) -> torch.Tensor:
        return torch.cat([parameter.detach().flatten().clone() for parameter in module.parameters()])

    def recorded(self, policy):
        target = target_network(self, policy)
        calls.append({"training": policy.training, "weights": flat(policy), "target": flat(target)})
        return target

    ConsistencyDistillationObjective._target_network = recorded
    atexit.register(lambda: torch.save(calls, f"{record}-{rank}-targets.pt"))


def loader_generators() -> None:
    """Give every DataLoader a generator of its own (seeded 0) where it is given none."""
    import torch
    from torch.utils.data import DataLoader

    make = DataLoader.__init__

    def with_generator(self, *arguments, generator=None, **options):
        make(self, *arguments, generator=generator or torch.Generator().manual_seed(0), **options)

    DataLoader.__init__ = with_generator


def main() -> None:
    record, run, kill_at, probe, command, *arguments = sys.argv[1:]
    rank = int(os.environ.get("RANK", "0"))
    watch_writes(Path(os.path.abspath(run)), Path(record), rank)
    if int(kill_at):
        kill_after_checkpoint(command, int(kill_at))
    if probe == "targets":
        probe_targets(Path(record), rank)
    if probe == "loader-generator":
        loader_generators()
    with tiny_pi05() if probe == "tiny-pi05" else contextlib.nullcontext():
        run_command(command, arguments)


def tiny_pi05() -> contextlib.AbstractContextManager:
    """LeRobot's pi0.5 at the tests' tiny size while the command runs."""
    sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the repository: the tests' tiny builds
    from tests.lerobot_tiny import tiny_pi_configs

    return tiny_pi_configs("pi05")


def run_command(command: str, arguments: list[str]) -> None:
    if command == "lerobot-train":
        from lerobot.scripts.lerobot_train import main as lerobot_train

        sys.argv = ["lerobot-train", *arguments]
        lerobot_train()
        return
    from snapflow.cli import main as snapflow

    code = snapflow(arguments)
    sys.stdout.flush()
    if code:
        sys.exit(code)


if __name__ == "__main__":
    main()
