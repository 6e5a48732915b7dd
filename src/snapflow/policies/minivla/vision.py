"""MiniVLA's convolutional camera encoder: a small ConvNet, its feature map pooled by a spatial softmax into keypoint
tokens, and DrQ's random-shift augmentation in training (see :class:`~snapflow.policies.minivla.MiniVLAConfig`)."""

from __future__ import annotations

import torch
from torch import Tensor, nn
from torch.nn import functional as F

from snapflow.policies.minivla.configuration import NORM_GROUPS


def random_shift(images: Tensor, pad: int) -> Tensor:
    """Each image (B, C, H, W) shifted by its own whole number of pixels in [-pad, pad] along each axis, the border
    repeated where the shift uncovers it (DrQ: pad by replication, then crop back at a random offset)."""
    batch, _, height, width = images.shape
    padded = F.pad(images, (pad, pad, pad, pad), mode="replicate")
    offsets = torch.randint(0, 2 * pad + 1, (batch, 2), device=images.device)
    rows = (offsets[:, 0, None] + torch.arange(height, device=images.device))[:, None, :, None]
    columns = (offsets[:, 1, None] + torch.arange(width, device=images.device))[:, None, None, :]
    samples = torch.arange(batch, device=images.device)[:, None, None, None]
    channels = torch.arange(images.shape[1], device=images.device)[None, :, None, None]
    return padded[samples, channels, rows, columns]


class SpatialSoftmax(nn.Module):
    """``keypoints`` learned maps over a feature map (B, C, H, W); each gives a token of where its softmax puts the
    weight (expected x and y in [-1, 1]) and what the features are there (their mean under that weight)."""

    def __init__(self, channels: int, keypoints: int) -> None:
        super().__init__()
        self.maps = nn.Conv2d(channels, keypoints, 1)

    def forward(self, features: Tensor) -> Tensor:
        batch, channels, height, width = features.shape
        weights = self.maps(features).flatten(2).softmax(-1)  # (B, K, H*W)
        ys, xs = torch.meshgrid(
            torch.linspace(-1, 1, height, device=features.device, dtype=features.dtype),
            torch.linspace(-1, 1, width, device=features.device, dtype=features.dtype),
            indexing="ij",
        )
        where = weights @ torch.stack([xs.flatten(), ys.flatten()], dim=-1)  # (B, K, 2)
        what = weights @ features.flatten(2).transpose(1, 2)  # (B, K, C)
        return torch.cat([where, what], dim=-1)


def _stage(inputs: int, outputs: int) -> nn.Sequential:
    """Halve the resolution, then one more convolution at it; GroupNorm, as Diffusion Policy puts in place of
    BatchNorm (batch statistics drift under a weight average and at batch 1)."""
    return nn.Sequential(
        nn.Conv2d(inputs, outputs, 3, stride=2, padding=1),
        nn.GroupNorm(NORM_GROUPS, outputs),
        nn.SiLU(),
        nn.Conv2d(outputs, outputs, 3, padding=1),
        nn.GroupNorm(NORM_GROUPS, outputs),
        nn.SiLU(),
    )


class ConvEncoder(nn.Module):
    """One camera's uint8 frames (B, 3, S, S) to ``keypoints`` tokens of ``width``."""

    def __init__(self, width: int, keypoints: int, channels: int, downsample: int, shift: int) -> None:
        super().__init__()
        self.downsample, self.shift = downsample, shift
        self.stages = nn.Sequential(
            _stage(3, channels), _stage(channels, 2 * channels), _stage(2 * channels, 4 * channels)
        )
        self.pool = SpatialSoftmax(4 * channels, keypoints)
        self.project = nn.Linear(4 * channels + 2, width)

    def forward(self, images: Tensor) -> Tensor:
        x = images.float() / 255.0 - 0.5
        if self.downsample > 1:
            x = F.avg_pool2d(x, self.downsample)
        if self.training and self.shift:
            x = random_shift(x, self.shift)
        return self.project(self.pool(self.stages(x)))


__all__ = ["ConvEncoder", "SpatialSoftmax", "random_shift"]
