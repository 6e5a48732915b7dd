"""The linear probability path shared by pi0, pi0.5 and SmolVLA.

Convention: t = 1 is pure noise, t = 0 is data, so samplers integrate from t = 1 down to t = 0.
"""

from __future__ import annotations

from torch import Tensor


def broadcast_time(t: Tensor, like: Tensor) -> Tensor:
    """Reshape a per-sample time of shape (B,) so it broadcasts over a (B, ...) tensor."""
    if t.ndim != 1 or t.shape[0] != like.shape[0]:
        raise ValueError(f"time must have shape ({like.shape[0]},), got {tuple(t.shape)}")
    return t.reshape(-1, *([1] * (like.ndim - 1))).to(like.dtype)


def interpolate(actions: Tensor, noise: Tensor, t: Tensor) -> Tensor:
    """Point x_t = (1 - t) * a + t * eps on the straight path from data a (t = 0) to noise eps (t = 1)."""
    if actions.shape != noise.shape:
        raise ValueError(f"actions {tuple(actions.shape)} and noise {tuple(noise.shape)} differ in shape")
    t = broadcast_time(t, actions)
    return (1 - t) * actions + t * noise


def conditional_velocity(actions: Tensor, noise: Tensor) -> Tensor:
    """Velocity d x_t / d t = eps - a of the conditional path: the flow-matching regression target."""
    if actions.shape != noise.shape:
        raise ValueError(f"actions {tuple(actions.shape)} and noise {tuple(noise.shape)} differ in shape")
    return noise - actions


def euler_step(x: Tensor, velocity: Tensor, t: Tensor, t_next: Tensor) -> Tensor:
    """Move x from time t to time t_next along ``velocity``: x + (t_next - t) * v (t_next < t when denoising)."""
    return x + broadcast_time(t_next - t, x) * velocity


__all__ = ["broadcast_time", "interpolate", "conditional_velocity", "euler_step"]
