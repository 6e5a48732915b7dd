"""Training objectives; they see a policy only through :class:`snapflow.protocol.FlowPolicy`."""

from snapflow.objective.snapflow import SnapFlowLossOutput, SnapFlowObjective, two_step_shortcut_target

__all__ = ["SnapFlowObjective", "SnapFlowLossOutput", "two_step_shortcut_target"]
