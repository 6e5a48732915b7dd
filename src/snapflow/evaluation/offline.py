"""Offline action error on held-out demonstration chunks, as the paper's Table 2 reports it."""

from __future__ import annotations

import torch

from snapflow.data.chunks import ChunkData
from snapflow.evaluation.config import OFFLINE_SAMPLES
from snapflow.evaluation.results import OfflineMetrics
from snapflow.flow.modes import SamplingMode
from snapflow.flow.solver import sample_actions
from snapflow.protocol import FlowPolicy, draw_flow_noise


@torch.no_grad()
def offline_metrics(
    policy: FlowPolicy,
    data: ChunkData,
    mode: SamplingMode,
    max_samples: int = OFFLINE_SAMPLES,
    seed: int = 0,
    batch_size: int = 250,
) -> OfflineMetrics:
    """Per-sample MSE of the predicted chunk (normalised action space) summarised by mean, median, std,
    P90 and P95, and the mean cosine similarity of flattened chunks. Sample subset and noise are fixed by
    ``seed``, so every mode and checkpoint is scored on identical inputs."""
    generator = torch.Generator().manual_seed(seed)
    indices = torch.randperm(len(data), generator=generator)[:max_samples]
    noise = draw_flow_noise(policy, (len(indices), *data.actions.shape[1:]), generator)
    policy.eval()
    errors, cosines = [], []
    for start in range(0, len(indices), batch_size):
        observation, target = data.batch(indices[start : start + batch_size])
        prediction = sample_actions(policy, observation, noise[start : start + batch_size], mode)
        errors.append((prediction - target).pow(2).flatten(1).mean(1))
        cosines.append(torch.nn.functional.cosine_similarity(prediction.flatten(1), target.flatten(1), dim=1))
    mse, cosine = torch.cat(errors).double(), torch.cat(cosines).double()
    return OfflineMetrics(
        len(mse),
        mse.mean().item(),
        mse.median().item(),
        mse.std().item(),
        torch.quantile(mse, 0.90).item(),
        torch.quantile(mse, 0.95).item(),
        cosine.mean().item(),
    )


__all__ = ["offline_metrics"]
