"""Sinusoidal time features and the target-time embedding phi_s, SnapFlow's only new parameters."""

from __future__ import annotations

import functools
import math

import torch
from torch import Tensor, nn


def sinusoidal_features(t: Tensor, dim: int, min_period: float = 4e-3, max_period: float = 4.0) -> Tensor:
    """Features [sin(2 pi t / p_k), cos(2 pi t / p_k)] for ``dim // 2`` periods spaced geometrically, in float32.

    The default periods are those of pi0 / pi0.5 / SmolVLA, whose times live in [0, 1]. float32 throughout (no
    float64, no host sync), so the pass stays one graph where it is compiled or captured.
    """
    if dim % 2:
        raise ValueError(f"sinusoidal feature width must be even, got {dim}")
    if t.ndim != 1:
        raise ValueError(f"time must have shape (B,), got {tuple(t.shape)}")
    if torch.compiler.is_compiling():  # traced inline: a constant the compiler folds (a cached tensor would leak)
        frequencies = _frequencies(dim, min_period, max_period, t.device)
    else:
        frequencies = _cached_frequencies(dim, min_period, max_period, t.device)
    angles = t.to(torch.float32)[:, None] * frequencies[None, :]
    return torch.cat([angles.sin(), angles.cos()], dim=1)


def _frequencies(dim: int, min_period: float, max_period: float, device: torch.device) -> Tensor:
    """2 pi / p_k, computed in float64 and rounded once to float32."""
    fraction = torch.linspace(0.0, 1.0, dim // 2, device=device, dtype=torch.float64)
    return (2 * math.pi / (min_period * (max_period / min_period) ** fraction)).to(torch.float32)


@functools.lru_cache(maxsize=64)
def _cached_frequencies(dim: int, min_period: float, max_period: float, device: torch.device) -> Tensor:
    """:func:`_frequencies` built once per width and device in eager mode: every denoising pass needs them, and
    rebuilding them was a measurable share of a one-step pass of a small policy."""
    with torch.inference_mode(False):  # a cached inference tensor could not take part in later training
        return _frequencies(dim, min_period, max_period, device)


class TargetTimeEmbedding(nn.Module):
    """phi_s(s) = Linear2(SiLU(Linear1(sinusoid(s)))), added to the policy's own time embedding.

    Only Linear2 starts at zero (weights and bias), so the wrapped policy is bit-for-bit the teacher at
    step 0 while Linear1 keeps a normal init: were both zero, SiLU(0) = 0 would leave only Linear2's bias
    with a gradient and phi_s would collapse to a constant that ignores s. Linear1's init is drawn from a fixed
    seed, the global random state restored after: a teacher wrapped twice (each opening of a LeRobot teacher
    folder, which has no phi_s) gets the same weights, so whatever digests them (an evaluation's log identity)
    sees the same policy, and wrapping leaves the global random stream where it was.
    """

    def __init__(
        self,
        output_dim: int,
        sinusoid_dim: int | None = None,
        hidden_dim: int | None = None,
        min_period: float = 4e-3,
        max_period: float = 4.0,
    ) -> None:
        super().__init__()
        self.sinusoid_dim = sinusoid_dim or output_dim + output_dim % 2
        self.min_period = min_period
        self.max_period = max_period
        with torch.random.fork_rng(devices=[]):  # nn.Linear's own init, seeded; the global stream restored
            torch.manual_seed(0)
            self.linear_in = nn.Linear(self.sinusoid_dim, hidden_dim or output_dim)
            self.linear_out = nn.Linear(hidden_dim or output_dim, output_dim)
        nn.init.zeros_(self.linear_out.weight)
        nn.init.zeros_(self.linear_out.bias)

    def forward(self, s: Tensor) -> Tensor:
        features = sinusoidal_features(s, self.sinusoid_dim, self.min_period, self.max_period)
        features = features.to(self.linear_in.weight.dtype)
        return self.linear_out(nn.functional.silu(self.linear_in(features)))


__all__ = ["sinusoidal_features", "TargetTimeEmbedding"]
