"""The benchmark registry: each name builds its benchmark, and an unknown name is named."""

from __future__ import annotations

import pytest

from snapflow.envs.base import Benchmark
from snapflow.envs.factory import BENCHMARKS, DEFAULT_BENCHMARK, make_benchmark
from snapflow.envs.libero import Libero
from snapflow.envs.metaworld import MetaWorld


def test_each_registered_name_builds_the_benchmark_of_that_name():
    """metaworld is plain MT10 (and the default), metaworld-via-points its multimodal variant, libero LIBERO and
    libero-lod LIBERO whose cameras draw simplified meshes."""
    names = {"metaworld", "metaworld-via-points", "libero", "libero-lod"}
    assert set(BENCHMARKS) == names and DEFAULT_BENCHMARK == "metaworld"
    for name, via in (("metaworld", False), ("metaworld-via-points", True)):
        benchmark = make_benchmark(name)
        assert isinstance(benchmark, MetaWorld) and isinstance(benchmark, Benchmark)
        assert benchmark.name == name and benchmark.via_points is via
    assert make_benchmark().name == DEFAULT_BENCHMARK
    for name, triangles in (("libero", None), ("libero-lod", 5000)):
        benchmark = make_benchmark(name)
        assert isinstance(benchmark, Libero) and (benchmark.name, benchmark.mesh_triangles) == (name, triangles)


def test_an_unknown_environment_is_named_with_the_known_ones():
    """The error names the environment asked for and lists the registered ones."""
    with pytest.raises(
        ValueError,
        match="unknown environment 'pusht'; choose one of metaworld, metaworld-via-points, libero, libero-lod",
    ):
        make_benchmark("pusht")
