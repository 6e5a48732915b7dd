"""Checks of a written PNG figure: it decodes, has the size its figure was drawn at, and shows the colours of what
it plots (matplotlib's default cycle: C0 #1f77b4, C1 #ff7f0e, C2 #2ca02c, ...)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

CYCLE = ["#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd"]


def read_png(path: Path) -> np.ndarray:
    """(height, width, 3) uint8 pixels of a PNG file."""
    from PIL import Image

    assert Path(path).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n", f"{path} is not a PNG"
    with Image.open(path) as image:
        return np.asarray(image.convert("RGB"))


def tint_share(pixels: np.ndarray, colour: str, min_alpha: float = 0.3, tolerance: float = 0.06) -> float:
    """Share of the pixels that are ``colour`` drawn over white with some alpha >= ``min_alpha`` (semi-transparent
    markers, alone or overlapping): one alpha explains every channel within ``tolerance``."""
    rgb = np.array([int(colour[i : i + 2], 16) for i in (1, 3, 5)], dtype=float)
    darkening = 255.0 - pixels.astype(float)  # alpha * (255 - colour) per channel
    span = 255.0 - rgb
    channels = span > 40  # the channels the colour darkens enough to read an alpha from
    alpha = darkening[..., channels] / span[channels]
    consistent = (alpha.max(axis=-1) - alpha.min(axis=-1) <= tolerance) & (alpha.min(axis=-1) >= min_alpha)
    flat = np.abs(darkening[..., ~channels] - alpha.mean(axis=-1, keepdims=True) * span[~channels]) <= 255 * tolerance
    return float((consistent & flat.all(axis=-1)).mean())


def colour_share(pixels: np.ndarray, colour: str, tolerance: int = 3) -> float:
    """Share of the pixels within ``tolerance`` (per channel) of ``colour`` (#rrggbb)."""
    rgb = np.array([int(colour[i : i + 2], 16) for i in (1, 3, 5)])
    return float((np.abs(pixels.astype(int) - rgb).max(axis=-1) <= tolerance).mean())


def assert_figure(
    path: Path, size_inches: tuple[float, float], colours: dict[str, float] | None = None, dpi: int = 110
) -> np.ndarray:
    """The PNG at ``path`` is ``size_inches`` (width, height) at ``dpi``, is not blank, and each of ``colours`` covers at
    least the given share of it. Returns its pixels."""
    pixels = read_png(path)
    width, height = size_inches
    assert pixels.shape == (round(height * dpi), round(width * dpi), 3), f"{path}: {pixels.shape}"
    assert len(np.unique(pixels.reshape(-1, 3), axis=0)) > 10, f"{path} is blank"
    for colour, share in (colours or {}).items():
        assert colour_share(pixels, colour) >= share, (
            f"{path}: {colour} covers {colour_share(pixels, colour):.4f} < {share}"
        )
    return pixels
