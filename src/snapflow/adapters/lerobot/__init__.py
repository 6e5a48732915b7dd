"""LeRobot's pi0, pi0.5, SmolVLA, X-VLA and multi-task DiT under SnapFlow, without editing LeRobot's code.

Needs ``pip install "snapflow-vla[lerobot]"``: lerobot 0.4.4 (SmolVLA) on Python 3.11, lerobot >= 0.5 (all five)
on Python >= 3.12.
"""

from snapflow import install_command

try:
    import lerobot  # noqa: F401
except ImportError as error:  # pragma: no cover - depends on the environment
    raise ModuleNotFoundError(
        f"the LeRobot adapters need LeRobot: {install_command('lerobot')}", name="lerobot"
    ) from error

from snapflow.adapters.lerobot.base import LeRobotFlowPolicy
from snapflow.adapters.lerobot.checkpoint import load_distilled, load_pretrained_policy, save_distilled
from snapflow.adapters.lerobot.multi_task_dit import MultiTaskDiTFlowPolicy
from snapflow.adapters.lerobot.pi0 import PI0FlowPolicy, PI05FlowPolicy
from snapflow.adapters.lerobot.registry import wrap_policy
from snapflow.adapters.lerobot.smolvla import SmolVLAFlowPolicy
from snapflow.adapters.lerobot.xvla import XVLAFlowPolicy

__all__ = [
    "LeRobotFlowPolicy",
    "MultiTaskDiTFlowPolicy",
    "PI0FlowPolicy",
    "PI05FlowPolicy",
    "SmolVLAFlowPolicy",
    "XVLAFlowPolicy",
    "wrap_policy",
    "load_pretrained_policy",
    "save_distilled",
    "load_distilled",
]
