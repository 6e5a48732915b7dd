"""Several primitives one after another, for a goal of several predicates (LIBERO-10's two-step tasks)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from snapflow.envs.base import Observation
from snapflow.envs.libero_expert.motion import Primitive


class InSequence:
    """Run ``steps`` in order: each takes over, planning from the scene as it is then, once the one before has
    finished its work and risen clear of it; each turns the hand from its orientation at the episode's start, not
    from where the one before left it."""

    def __init__(self, steps: Sequence[Primitive]) -> None:
        if not steps:
            raise ValueError("a sequence needs at least one primitive")
        self.steps = tuple(steps)

    def reset(self, observation: Observation) -> None:
        self.index = 0
        self.upright = np.asarray(observation.privileged["robot0_eef_quat"], dtype=float)
        self.steps[0].reset(observation)

    @property
    def current(self) -> Primitive:
        """The primitive acting now."""
        return self.steps[self.index]

    def act(self, observation: Observation) -> np.ndarray:
        if self.current.finished and self.index + 1 < len(self.steps):
            self.index += 1
            self.current.reset(observation, self.upright)
        return self.current.act(observation)
