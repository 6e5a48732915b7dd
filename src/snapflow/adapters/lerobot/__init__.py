"""LeRobot policies under SnapFlow, without editing LeRobot's code. Needs ``pip install "snapflow[lerobot]"``."""

from snapflow.adapters.lerobot.smolvla import SmolVLAFlowPolicy, load_smolvla, save_smolvla

__all__ = ["SmolVLAFlowPolicy", "save_smolvla", "load_smolvla"]
