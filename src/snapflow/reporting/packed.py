"""A folder kept as one file: what a finished job leaves that another machine needs and that is many small files (a
task's demonstrations as a LeRobotDataset: meta, parquet and video files), packed to be committed and archived in
history (:mod:`snapflow.reporting.archive`) as weights are.

The pack is an uncompressed tar (the files inside are compressed already: video, parquet) written deterministically
(sorted names, no owners, no times), so the same folder packs to the same bytes and git stores it once.
"""

from __future__ import annotations

import os
import shutil
import tarfile
import tempfile
from pathlib import Path

from snapflow.reporting.files import atomic_write

PACKED_SUFFIX = ".tar"


def pack_folder(folder: str | Path, packed: str | Path) -> Path:
    """Write every file under ``folder`` into the tar ``packed`` (whole or not at all), named relative to
    ``folder``; returns ``packed``. Hidden names are left out, with all under them: a runner's pending record, the
    staging folder of a write that a killed process left."""
    folder = Path(folder)
    files = sorted(
        path
        for path in folder.rglob("*")
        if path.is_file() and not any(part.startswith(".") for part in path.relative_to(folder).parts)
    )

    def write(temporary: Path) -> None:
        with tarfile.open(temporary, "w", format=tarfile.PAX_FORMAT) as archive:
            for path in files:
                info = tarfile.TarInfo(path.relative_to(folder).as_posix())
                info.size, info.mode = path.stat().st_size, 0o644
                with path.open("rb") as data:
                    archive.addfile(info, data)

    return atomic_write(packed, write)


def unpack_folder(packed: str | Path, folder: str | Path) -> Path:
    """Extract the tar ``packed`` into ``folder`` (replacing what is there) by way of a folder beside it, so that
    ``folder`` holds the whole pack or what it held before; only plain files inside ``folder`` are extracted
    (tarfile's ``data`` filter). Returns ``folder``."""
    folder = Path(folder)
    folder.parent.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=f".{folder.name}.unpacking-", dir=folder.parent))
    try:
        with tarfile.open(packed) as archive:
            archive.extractall(staging / "folder", filter="data")
        shutil.rmtree(folder, ignore_errors=True)
        os.replace(staging / "folder", folder)
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    return folder


__all__ = ["PACKED_SUFFIX", "pack_folder", "unpack_folder"]
