"""The one figure writer: matplotlib on its file-only backend, PNGs written atomically."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from snapflow.reporting.files import atomic_write


def pyplot() -> Any:
    """matplotlib.pyplot on the file-only Agg backend (no display needed)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def save_figure(figure: Any, path: str | Path, dpi: int = 110) -> Path:
    """Write ``figure`` as a PNG (whole or not at all) and close it."""
    try:
        return atomic_write(path, lambda temporary: figure.savefig(temporary, dpi=dpi, format="png"))
    finally:
        pyplot().close(figure)


__all__ = ["pyplot", "save_figure"]
