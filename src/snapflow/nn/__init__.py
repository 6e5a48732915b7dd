"""Neural building blocks SnapFlow adds to a policy."""

from snapflow.nn.snapflow_policy import SnapFlowPolicy
from snapflow.nn.time_embedding import TargetTimeEmbedding, sinusoidal_features

__all__ = ["SnapFlowPolicy", "TargetTimeEmbedding", "sinusoidal_features"]
