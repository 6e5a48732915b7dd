"""Shared fixtures."""

from __future__ import annotations

import pytest
import torch
from torch import Tensor

from snapflow.nn import SnapFlowPolicy
from tests.helpers import ACTION_DIM, CHUNK, OBSERVATION_DIM, make_model, randomise_target_time


@pytest.fixture
def student() -> SnapFlowPolicy:
    return randomise_target_time(SnapFlowPolicy(make_model()))


@pytest.fixture
def batch() -> tuple[Tensor, Tensor]:
    generator = torch.Generator().manual_seed(7)
    return torch.randn(6, OBSERVATION_DIM, generator=generator), torch.randn(6, CHUNK, ACTION_DIM, generator=generator)
