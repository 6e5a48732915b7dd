"""The registry of benchmarks by name; the CLI's ``--env`` choices and the demonstrations' ``env`` field read it."""

from __future__ import annotations

from collections.abc import Callable

from snapflow.envs.base import Benchmark
from snapflow.envs.libero import Libero
from snapflow.envs.libero_lod import CAP
from snapflow.envs.metaworld import MetaWorld
from snapflow.errors import InvalidInputError

BENCHMARKS: dict[str, Callable[[], Benchmark]] = {
    "metaworld": MetaWorld,
    "metaworld-via-points": lambda: MetaWorld(via_points=True),
    "libero": Libero,
    # the cameras draw simplified visual meshes (frames within ~1 of 255 of LIBERO's, in about half the time)
    "libero-lod": lambda: Libero(mesh_triangles=CAP),
}
DEFAULT_BENCHMARK = "metaworld"


def make_benchmark(name: str = DEFAULT_BENCHMARK) -> Benchmark:
    """The benchmark registered as ``name``, or a ValueError listing the known ones."""
    if name not in BENCHMARKS:
        raise InvalidInputError(f"unknown environment {name!r}; choose one of {', '.join(BENCHMARKS)}")
    return BENCHMARKS[name]()


__all__ = ["BENCHMARKS", "DEFAULT_BENCHMARK", "make_benchmark"]
