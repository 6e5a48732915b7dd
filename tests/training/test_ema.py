"""The average of the trained weights (TrainConfig.ema_decay): its update written out by hand, the checkpoints that
save it as the policy and keep the raw weights for resuming, and runs recorded before the option existed."""

from __future__ import annotations

import json
import shutil
from dataclasses import replace

import pytest
import torch
from safetensors.torch import load_file

from snapflow.cli import main
from snapflow.policies.checkpoint import load_policy
from snapflow.training.checkpoint import TRAINING_WEIGHTS
from snapflow.training.config import TrainConfig
from snapflow.training.ema import WeightAverage
from snapflow.training.recipes import DistillSettings
from snapflow.training.stages import distill, train_teacher
from tests.training.fixtures import TINY, synthetic_demonstrations, train_config

DECAY = 0.6  # small, so the warm-up (1 + k) / (10 + k) and the decay both act within six steps


@pytest.fixture(scope="module")
def demonstrations(tmp_path_factory):
    return synthetic_demonstrations().save(tmp_path_factory.mktemp("demos"))


def _checkpoint(run, step: int, name: str = "policy.safetensors") -> dict[str, torch.Tensor]:
    return load_file(run / "checkpoints" / f"step_{step:07d}" / name)


def test_the_average_follows_its_formula_written_out():
    weight = torch.nn.Parameter(torch.tensor([0.0, 10.0]))
    average = WeightAverage({"w": weight}, decay=0.5)
    expected = torch.tensor([0.0, 10.0])
    for step, value in enumerate([[1.0, 2.0], [3.0, 4.0], [5.0, 6.0], [7.0, 8.0]]):
        with torch.no_grad():
            weight.copy_(torch.tensor(value))
        average.update(step)
        kept = min(0.5, (1 + step) / (10 + step))  # 0.1, 2/11, 3/12, 4/13: the warm-up, below the decay
        expected = kept * expected + (1 - kept) * torch.tensor(value)
        assert torch.allclose(average.average["w"], expected)
    assert average.decay_at(8) == 0.5 and average.decay_at(0) == pytest.approx(0.1)
    with average.applied() as raw:
        assert torch.equal(weight.detach(), average.average["w"]) and torch.equal(raw["w"], torch.tensor([7.0, 8.0]))
    assert torch.equal(weight.detach(), torch.tensor([7.0, 8.0])), "the raw weights are back after the block"
    with pytest.raises(ValueError, match="between 0 and 1"):
        WeightAverage({"w": weight}, decay=1.0)
    with pytest.raises(ValueError, match="between 0 and 1"):
        TrainConfig(ema_decay=0.0)


def test_checkpoints_save_the_average_as_the_policy_and_training_is_unchanged(demonstrations, tmp_path):
    every_step = replace(train_config(6), checkpoint_every=1, keep_checkpoints=10)
    train_teacher(demonstrations, tmp_path / "plain", TINY, every_step, progress=False)
    train_teacher(demonstrations, tmp_path / "averaged", TINY, replace(every_step, ema_decay=DECAY), progress=False)
    plain, averaged = tmp_path / "plain", tmp_path / "averaged"
    assert not (plain / "checkpoints" / "step_0000001" / TRAINING_WEIGHTS).exists()
    # the average is a copy: the run trains exactly the same weights
    initial = load_policy(averaged / "checkpoints" / "step_0000001").policy  # only to name the parameters
    names = [name for name, _ in initial.named_parameters()]
    average = None
    for step in range(1, 7):
        raw = _checkpoint(averaged, step, TRAINING_WEIGHTS)
        assert sorted(raw) == sorted(names)
        assert all(torch.equal(raw[name], _checkpoint(plain, step)[name]) for name in names)
        if average is None:  # step 1's average holds the initial weights' share; from there, by hand
            average = _checkpoint(averaged, 1)
            continue
        kept = min(DECAY, step / (9 + step))  # after optimiser step k = step - 1
        average = {n: kept * average[n] + (1 - kept) * raw[n] for n in names}
        saved = _checkpoint(averaged, step)
        assert all(torch.allclose(saved[n], average[n], atol=1e-6) for n in names), step
    final = _checkpoint(averaged, 6)
    assert any(not torch.equal(final[n], _checkpoint(plain, 6)[n]) for n in names), "the policy is the average"
    assert json.loads((averaged / "history.json").read_text())["train_config"]["ema_decay"] == DECAY


def test_a_resumed_averaged_run_ends_as_the_straight_one(demonstrations, tmp_path):
    config = train_config(6, ema_decay=DECAY)
    straight = train_teacher(demonstrations, tmp_path / "straight", TINY, config, progress=False)
    interrupted = tmp_path / "interrupted"
    train_teacher(demonstrations, interrupted, TINY, config, progress=False)
    (interrupted / "latest.json").write_text(json.dumps({"checkpoint": "checkpoints/step_0000003"}))
    shutil.rmtree(interrupted / "checkpoints" / "step_0000006")
    resumed = train_teacher(demonstrations, interrupted, TINY, config, resume=True, progress=False)
    assert [h["loss"] for h in resumed["history"]] == [h["loss"] for h in straight["history"]]
    for name in ("policy.safetensors", TRAINING_WEIGHTS):
        a, b = _checkpoint(tmp_path / "straight", 6, name), _checkpoint(interrupted, 6, name)
        assert a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a), name


def test_a_student_averages_only_what_it_trains(demonstrations, tmp_path):
    teacher = tmp_path / "teacher"
    train_teacher(demonstrations, teacher, TINY, train_config(3), progress=False)
    student = tmp_path / "student"
    distill(teacher, demonstrations, student, train_config(3, ema_decay=DECAY), DistillSettings(), progress=False)
    raw = _checkpoint(student, 3, TRAINING_WEIGHTS)
    policy = load_policy(student).policy
    expert = {id(parameter) for parameter in policy.expert_parameters()}
    assert set(raw) == {name for name, parameter in policy.named_parameters() if id(parameter) in expert}
    assert "target_time_embedding.linear_out.weight" in raw
    teacher_weights, student_weights = _checkpoint(teacher, 3), _checkpoint(student, 3)
    frozen = [name for name in teacher_weights if name not in raw]
    assert frozen and all(torch.equal(teacher_weights[n], student_weights[n]) for n in frozen), "frozen stays put"


def test_a_run_recorded_before_the_option_existed_resumes(demonstrations, tmp_path):
    run = tmp_path / "run"
    train_teacher(demonstrations, run, TINY, train_config(6), progress=False)
    (run / "latest.json").write_text(json.dumps({"checkpoint": "checkpoints/step_0000003"}))
    shutil.rmtree(run / "checkpoints" / "step_0000006")
    state_file = run / "checkpoints" / "step_0000003" / "trainer_state.json"
    state = json.loads(state_file.read_text())
    assert "ema_decay" not in state["train_config"], "an option at its default is left out of the record"
    state_file.write_text(json.dumps(state))
    resumed = train_teacher(demonstrations, run, TINY, train_config(6), resume=True, progress=False)
    assert resumed["step"] == 6
    with pytest.raises(ValueError, match=r"differ from the checkpoint's in \['ema_decay'\]"):
        train_teacher(demonstrations, run, TINY, train_config(6, ema_decay=0.9), resume=True, progress=False)


def test_the_commands_take_the_average(demonstrations, tmp_path):
    teacher, student = tmp_path / "teacher", tmp_path / "student"
    common = ["--data", str(demonstrations), "--steps", "2", "--batch-size", "8", "--no-progress"]
    assert main(["train", *common, "--output", str(teacher), "--ema-decay", "0.9"]) == 0
    assert main(["distill", *common, "--teacher", str(teacher), "--output", str(student), "--ema-decay", "0.99"]) == 0
    for run in (teacher, student):
        assert (run / "checkpoints" / "step_0000002" / TRAINING_WEIGHTS).is_file()
    assert json.loads((student / "history.json").read_text())["train_config"]["ema_decay"] == 0.99
