"""The evaluation tests' scripted benchmark, registered for each test that asks for it, and the tiny runs they evaluate."""

import pytest

from snapflow.envs import factory
from snapflow.policies.checkpoint import load_policy
from snapflow.policies.factory import default_config
from snapflow.training.recipes import DistillSettings
from snapflow.training.stages import distill, train_teacher
from tests.evaluation.scripted import ScriptedBenchmark
from tests.training.fixtures import ACTION_DIM, STATE_DIM, SYNTHETIC_TASKS, synthetic_demonstrations, train_config


@pytest.fixture
def scripted(monkeypatch) -> ScriptedBenchmark:
    monkeypatch.setitem(factory.BENCHMARKS, ScriptedBenchmark.name, ScriptedBenchmark)  # reports name their benchmark
    return ScriptedBenchmark()


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """Demonstrations, an MLP teacher and its SnapFlow student, trained a few steps."""
    root = tmp_path_factory.mktemp("runs")
    data = synthetic_demonstrations(episodes_per_task=5).save(root / "demos")
    config = default_config(
        "mlp",
        STATE_DIM,
        ACTION_DIM,
        list(SYNTHETIC_TASKS.values()),
        chunk_length=4,
        hidden_dim=32,
        time_embedding_dim=16,
    )
    train_teacher(data, root / "teacher", config, train_config(3), val_fraction=0.2, progress=False)
    distill(root / "teacher", data, root / "student", train_config(3), DistillSettings(), progress=False)
    return data, load_policy(root / "teacher"), load_policy(root / "student")
