"""Registers snapflow's SnapFlow students with LeRobot (``snapflow_smolvla``, ``snapflow_pi0``, ``snapflow_pi05``)
when LeRobot imports its third-party plugins."""

from snapflow.adapters.lerobot.plugin import *  # noqa: F403 - importing registers the types
from snapflow.adapters.lerobot.plugin import __all__  # noqa: F401
