"""Shared fixtures, and a sealed Hugging Face environment for the whole session."""

from __future__ import annotations

import atexit
import collections
import os
import shutil
import tempfile
from pathlib import Path

# Nothing may come from a hub, and no test may read or write the user's Hugging Face cache: point it at a fresh
# folder before anything imports huggingface_hub (which reads these variables once, at import)
os.environ["HF_HUB_OFFLINE"] = os.environ["TRANSFORMERS_OFFLINE"] = "1"
os.environ["HF_HUB_CACHE"] = tempfile.mkdtemp(prefix="snapflow-tests-hf-cache-")
atexit.register(shutil.rmtree, os.environ["HF_HUB_CACHE"], ignore_errors=True)
# Under pytest-xdist (`-n auto`: one worker a core) each worker, and every process it starts, computes on one thread:
# two workers of two threads each on two cores wait on each other's time slices, several times slower
if "PYTEST_XDIST_WORKER" in os.environ:
    os.environ["OMP_NUM_THREADS"] = os.environ["MKL_NUM_THREADS"] = "1"

import pytest  # noqa: E402
import torch  # noqa: E402
from torch import Tensor  # noqa: E402

if "PYTEST_XDIST_WORKER" in os.environ:
    torch.set_num_threads(1)

from snapflow.nn import SnapFlowPolicy  # noqa: E402
from tests.helpers import ACTION_DIM, CHUNK, OBSERVATION_DIM, make_model, randomise_target_time  # noqa: E402

ADAPTER_TESTS = Path(__file__).parent / "adapters"


def pytest_configure(config: pytest.Config) -> None:
    """Under ``--dist loadscope`` the workers take the modules (and classes) in collection order, heaviest first
    (:class:`HeaviestFirst`): pytest-xdist's own order, most tests first, put the heaviest last (a tutorial session
    or a tiny sweep is one test of minutes), and one worker ran them while the other had nothing left."""
    if hasattr(config.option, "loadscopereorder"):  # pytest-xdist's option; absent under -p no:xdist
        config.option.loadscopereorder = False
    config.pluginmanager.register(HeaviestFirst(), "snapflow-heaviest-first")


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """Marks every test under tests/adapters `lerobot` (they all run LeRobot), so `-m lerobot` selects them."""
    for item in items:
        if ADAPTER_TESTS in item.path.parents:
            item.add_marker(pytest.mark.lerobot)


class HeaviestFirst:
    """Collects the modules that hold slow tests first, those of fewest selected tests first: longest first is what
    balances two workers, and a slow module of one or two tests is one whole chain (a tutorial session, a sweep),
    minutes long; the fast modules then fill in around the slow ones' ends. Each module keeps its own order."""

    @pytest.hookimpl(trylast=True)  # after `-m` has deselected: the sizes are of what runs
    def pytest_collection_modifyitems(self, items: list[pytest.Item]) -> None:
        sizes = collections.Counter(item.path for item in items)
        slow_modules = {item.path for item in items if item.get_closest_marker("slow")}

        def heaviest_first(item: pytest.Item) -> tuple[bool, int]:
            return (False, sizes[item.path]) if item.path in slow_modules else (True, 0)

        items.sort(key=heaviest_first)  # a stable sort: each module stays contiguous


@pytest.fixture
def student() -> SnapFlowPolicy:
    """A small MLP student whose phi_s is non-zero, so its velocity depends on the target time s."""
    return randomise_target_time(SnapFlowPolicy(make_model()))


@pytest.fixture
def batch() -> tuple[Tensor, Tensor]:
    """Six observations (6, OBSERVATION_DIM) and their action chunks (6, CHUNK, ACTION_DIM)."""
    generator = torch.Generator().manual_seed(7)
    return torch.randn(6, OBSERVATION_DIM, generator=generator), torch.randn(6, CHUNK, ACTION_DIM, generator=generator)


@pytest.fixture(scope="session")
def teacher_checkpoint(tmp_path_factory) -> Path:
    """A tiny MiniVLA teacher's checkpoint folder after one training step on synthetic Meta-World-shaped episodes
    (its weights are not meant to act well): tests copy it before they change it."""
    from snapflow.training.config import TrainConfig
    from snapflow.training.stages import train_teacher
    from tests.training.fixtures import TINY, synthetic_demonstrations

    data = synthetic_demonstrations().save(tmp_path_factory.mktemp("data"))
    run = tmp_path_factory.mktemp("run")
    train_teacher(data, run, TINY, TrainConfig(steps=1, batch_size=4, checkpoint_every=1), progress=False)
    return run / "checkpoints" / "step_0000001"
