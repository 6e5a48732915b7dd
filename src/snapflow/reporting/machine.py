"""The machine behind a measured figure, named."""

from __future__ import annotations

import platform
from pathlib import Path
from typing import Any


def machine() -> dict[str, Any]:
    """CPU model, torch threads, GPU (or None), torch and Python versions."""
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
    }


def machine_description() -> str:
    """The machine of :func:`machine` in a few words, for titles and tables."""
    host = machine()
    return host["gpu"] or f"CPU {host['cpu']}, {host['threads']} threads"


__all__ = ["machine", "machine_description"]
