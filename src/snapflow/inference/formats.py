"""The export formats of a one-step student, by name: what ``snapflow export --format`` offers and what a loader
recognises in an export folder's record. Plain Python: the exporters and runtimes load on first use, so the CLI lists
the formats without importing torch.

A format is one :func:`register_export_format` call: the file it writes into the export folder, the function that
writes it (``(policy, observation, noise, path) -> record``, the policy being a
:class:`~snapflow.protocol.FlowPolicy` and ``observation`` / ``noise`` one example of its inputs; the record holds at
least ``file``, ``inputs`` and ``max_abs_difference_to_pytorch``, the exporter's own check of the file it wrote
against the policy on that example) and the runtime
that runs it again (a class built from the file's path, a :class:`~snapflow.protocol.FlowPolicy` that answers the one
jump). The folder writers (a built-in checkpoint's, a LeRobot folder's) and the loaders serve every registered format:
they keep the format's record under its name (``"onnx": {...}``) beside the policy's own description.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from snapflow._lazy import resolve
from snapflow.errors import InvalidInputError


@dataclass(frozen=True)
class ExportFormat:
    """One export format: ``file`` in the folder, written by ``exporter`` and run by ``runtime`` (``"module:name"``)."""

    name: str
    file: str
    exporter: str
    runtime: str

    def export(self, policy: Any, observation: Any, noise: Any, folder: Path) -> dict[str, Any]:
        """Write the one-step graph of ``policy`` into ``folder``; returns the format's record."""
        export: Callable[..., dict[str, Any]] = resolve(self.exporter)
        return export(policy, observation, noise, folder / self.file)

    def load(self, path: Path) -> Any:
        """The exported file at ``path`` as a policy that runs its one jump."""
        return resolve(self.runtime)(path)


EXPORT_FORMATS: dict[str, ExportFormat] = {}


def register_export_format(name: str, file: str, exporter: str, runtime: str) -> None:
    """Add export format ``name`` (see the module's description)."""
    if name in EXPORT_FORMATS:
        raise ValueError(f"an export format named {name!r} is registered already")
    EXPORT_FORMATS[name] = ExportFormat(name, file, exporter, runtime)


def export_format(name: str) -> ExportFormat:
    """The registered format ``name``, or a ValueError listing the known ones."""
    if name not in EXPORT_FORMATS:
        raise InvalidInputError(f"unknown export format {name!r}; choose one of {', '.join(EXPORT_FORMATS)}")
    return EXPORT_FORMATS[name]


def export_record(description: dict[str, Any]) -> tuple[ExportFormat, dict[str, Any]] | None:
    """The format and record of the export a folder's description holds (``policy.json``, a LeRobot folder's
    marker), or None for a policy that is not an export."""
    for name, entry in EXPORT_FORMATS.items():
        if name in description:
            return entry, description[name]
    return None


register_export_format(
    "onnx", "model.onnx", "snapflow.inference.onnx:export_onnx", "snapflow.inference.onnx:OnnxOneStepPolicy"
)


__all__ = ["ExportFormat", "EXPORT_FORMATS", "register_export_format", "export_format", "export_record"]
