"""``lerobot-train`` distils: a student type's ``forward`` is SnapFlow's objective (the VLM frozen, the settings in its
config's ``distill``), its ``update`` counts the step and records that the checkpoint was distilled, and a teacher
written as its student is the teacher, refusing the jump by name, until it is."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from dataclasses import asdict, replace
from importlib.metadata import version
from pathlib import Path

import pytest
import torch
from packaging.version import Version

pytest.importorskip("lerobot", reason="LeRobot is installed by the README's test command; this environment lacks it")

from snapflow.adapters.lerobot.registry import lerobot_time_sampler  # noqa: E402
from snapflow.adapters.lerobot.xvla import XVLAFlowPolicy  # noqa: E402
from snapflow.adapters.lerobot_types import PLUGIN_LEROBOT, lerobot_loads_plugins  # noqa: E402
from snapflow.errors import InvalidInputError  # noqa: E402
from snapflow.flow.modes import SamplingMode  # noqa: E402
from snapflow.flow.solver import sample_actions  # noqa: E402
from snapflow.objective.settings import DistillSettings  # noqa: E402
from tests.helpers import run_checked, run_tiny_lerobot_train  # noqa: E402
from tests.lerobot_tiny import build_tiny_smolvla, lerobot_sample, tiny_batch  # noqa: E402

PLUGINS = pytest.mark.skipif(
    not lerobot_loads_plugins(),
    reason=f"lerobot-train imports third-party policies from lerobot {PLUGIN_LEROBOT} on",
)


def _student(vlm_directory, **fields):
    """The tiny SmolVLA as its student type (phi_s at zero), its config's ``fields`` set before the policy is built."""
    from snapflow.adapters.lerobot.plugin import student_config, student_policy

    teacher = build_tiny_smolvla(vlm_directory)
    config = student_config(teacher.config)
    for name, value in fields.items():
        setattr(config, name, value)
    student = student_policy("smolvla")(config)
    student.load_state_dict(teacher.state_dict(), strict=False)  # phi_s stays at zero: the teacher
    return student


def test_the_student_types_forward_is_snapflows_objective_on_the_same_batch_and_generator(vlm_directory):
    student = _student(vlm_directory, distill=DistillSettings(consistency_weight=3.0, target_steps=4))
    batch = tiny_batch(batch_size=6)
    loss, logs = student.forward(dict(batch), generator=torch.Generator().manual_seed(7))
    loss.backward()
    gradients = {
        name: parameter.grad.clone() for name, parameter in student.named_parameters() if parameter.requires_grad
    }
    student.zero_grad()

    settings = student.config.distill
    assert (settings.consistency_weight, settings.target_steps) == (3.0, 4)
    objective = settings.objective(lerobot_time_sampler(student.config))
    expected = objective(
        student.snapflow, dict(batch), student.prepare_action(batch), generator=torch.Generator().manual_seed(7)
    )
    expected.loss.backward()
    assert torch.equal(loss, expected.loss)
    assert logs == {
        "flow_matching_loss": expected.flow_matching_loss.item(),
        "consistency_loss": expected.consistency_loss.item(),
    }
    assert expected.num_consistency == 3 and expected.consistency_loss > 0
    for name, parameter in student.named_parameters():
        if parameter.requires_grad:
            assert torch.equal(gradients[name], parameter.grad), name

    # what lerobot-train optimises: the action expert and phi_s, as snapflow distils; the VLM does not require grad
    trainable = {id(parameter) for parameter in student.snapflow.expert_parameters()}
    assert {id(parameter) for parameter in student.get_optim_params()} == trainable
    assert {id(parameter) for parameter in student.parameters() if parameter.requires_grad} == trainable
    assert not any(parameter.requires_grad for parameter in student.model.vlm_with_expert.vlm.parameters())
    with pytest.raises(ValueError, match="reduction='none'"):
        student.forward(dict(batch), reduction="none")


def test_the_high_noise_biased_fine_tuning_is_flow_matching_on_shifted_times(vlm_directory):
    """alpha 1 and time shift 4 (arXiv 2606.05737's recipe on the lerobot-train route): the loss is the policy's
    flow-matching loss at its own times shifted toward noise, with no consistency row."""
    from snapflow.flow.time_sampling import ShiftedTimeSampler
    from snapflow.objective.registry import make_objective

    student = _student(vlm_directory, distill=DistillSettings(alpha=1.0, time_shift=4.0))
    objective = student.distillation_objective()
    assert objective.time_sampler == ShiftedTimeSampler(lerobot_time_sampler(student.config), 4.0)

    batch = tiny_batch(batch_size=6)
    loss, logs = student.forward(dict(batch), generator=torch.Generator().manual_seed(7))
    unshifted = make_objective("snapflow", alpha=1.0, time_sampler=lerobot_time_sampler(student.config))
    on_shifted = make_objective("snapflow", alpha=1.0, time_sampler=objective.time_sampler)
    expected, other = (
        made(student.snapflow, dict(batch), student.prepare_action(batch), generator=torch.Generator().manual_seed(7))
        for made in (on_shifted, unshifted)
    )
    assert (expected.num_consistency, logs["consistency_loss"]) == (0, 0.0)
    assert torch.equal(loss, expected.loss) and not torch.equal(loss, other.loss)


def test_update_labels_the_checkpoint_distilled_only_after_a_step_of_the_one_step_objective(vlm_directory):
    from snapflow.adapters.lerobot.plugin.modeling_snapflow import NotDistilledError

    batch = tiny_batch()
    student = _student(vlm_directory, distilled=False)
    with pytest.raises(NotDistilledError, match=r"not distilled .* \(sampling_mode=teacher-10\)"):
        student.predict_action_chunk(dict(batch))
    student.forward(dict(batch))[0].backward()
    student.update()  # lerobot-train, after the optimiser step
    assert (student.config.distilled, student.config.steps_distilled) == (True, 1)
    assert student.predict_action_chunk(dict(batch)).shape == (4, 4, 4)

    # flow matching alone (alpha 1) trains no jump, and phi_s drifts at s = t: the label goes
    student.config.distill = replace(student.config.distill, alpha=1.0)
    student.forward(dict(batch))[0].backward()
    student.update()
    assert (student.config.distilled, student.config.steps_distilled) == (False, 2)

    # lambda 0 trains no jump by SnapFlow's target; the energy term alone does
    for target, distilled, steps in (("euler", False, 3), ("energy", True, 4)):
        student.config.distill = replace(student.config.distill, alpha=0.5, consistency_weight=0.0, target=target)
        student.forward(dict(batch))[0].backward()
        student.update()
        assert (student.config.distilled, student.config.steps_distilled) == (distilled, steps)


def _save_teacher(vlm_directory, directory: Path) -> Path:
    from lerobot.policies.factory import make_pre_post_processors

    teacher = build_tiny_smolvla(vlm_directory)
    teacher.save_pretrained(directory)
    stats = {"observation.state": {"mean": torch.zeros(6), "std": torch.ones(6)}}
    stats["action"] = {"mean": torch.zeros(4), "std": torch.ones(4)}
    for processor in make_pre_post_processors(teacher.config, dataset_stats=stats):
        processor.save_pretrained(directory)
    return directory


def test_a_teacher_written_as_its_student_is_the_teacher_until_distilled(vlm_directory, tmp_path, capsys):
    from snapflow.adapters.lerobot import save_distilled, wrap_policy
    from snapflow.adapters.lerobot.plugin import student_policy

    SnapFlowSmolVLAPolicy = student_policy("smolvla")  # noqa: N806
    from snapflow.adapters.lerobot.plugin.modeling_snapflow import NotDistilledError
    from snapflow.cli import main
    from snapflow.training.lerobot_student import write_student

    teacher = _save_teacher(vlm_directory, tmp_path / "teacher")
    student_folder = tmp_path / "student"
    arguments = ["distill", "--policy", str(teacher), "--lerobot-train", "--output", str(student_folder)]
    assert main([*arguments, "--recipe", "snapflow"]) == 0
    saved = json.loads((student_folder / "config.json").read_text())
    assert saved["type"] == "snapflow_smolvla" and saved["distilled"] is False
    assert saved["distill"]["consistency_weight"] == 3.0, "snapflow's recipe: lambda 3"
    assert (student_folder / "policy_preprocessor.json").is_file()

    student = SnapFlowSmolVLAPolicy.from_pretrained(student_folder)
    batch, noise = tiny_batch(), torch.randn(4, 4, 4, generator=torch.Generator().manual_seed(3))
    with pytest.raises(NotDistilledError):
        student.predict_action_chunk(dict(batch), noise=noise)
    student.config.sampling_mode = "teacher-10"  # read at every chunk
    plain = build_tiny_smolvla(vlm_directory)
    # equal to float32 rounding, not bit for bit (4.8e-7 apart on an AMD EPYC, where allclose's 1e-8 floor failed)
    torch.testing.assert_close(
        student.predict_action_chunk(dict(batch), noise=noise), lerobot_sample(plain, batch, noise, 10)
    )

    # snapflow's own distillation labels what it saves; a folder written before the label existed still samples
    save_distilled(wrap_policy(build_tiny_smolvla(vlm_directory)), tmp_path / "distilled")
    assert json.loads((tmp_path / "distilled" / "config.json").read_text())["distilled"] is True
    older = json.loads((tmp_path / "distilled" / "config.json").read_text())
    del older["distilled"]
    (tmp_path / "distilled" / "config.json").write_text(json.dumps(older))
    assert SnapFlowSmolVLAPolicy.from_pretrained(tmp_path / "distilled").config.mode.jump

    with pytest.raises(InvalidInputError, match=r"carries phi_s .* \(target_time false\)"):
        write_student(str(teacher), tmp_path / "ablation", DistillSettings(target_time=False))
    assert not (tmp_path / "ablation").exists(), "refused before anything is written"
    assert main([*arguments, "--steps", "10"]) == 2
    assert "give steps to lerobot-train" in capsys.readouterr().err


@pytest.mark.slow
@PLUGINS
def test_lerobot_train_takes_every_distillation_setting_as_a_flag_and_refuses_a_bad_one(vlm_directory, tmp_path):
    """``--policy.distill.<field>`` of ``lerobot-train`` itself: the settings its checkpoint's config holds, its step
    count, the prefix trained where ``freeze_prefix`` is false; a bad setting stops it before any step, named."""
    from safetensors.torch import load_file

    from snapflow.training.lerobot_student import write_student
    from tests.lerobot_tiny import write_tiny_dataset

    data = write_tiny_dataset(tmp_path / "data", episodes=2, frames=8)
    student = write_student(str(_save_teacher(vlm_directory, tmp_path / "teacher")), tmp_path / "student")
    flags = ["--log_freq=1", "--policy.distill.target_steps=[2,4]", "--policy.distill_steps=2"]
    flags += ["--policy.distill.freeze_prefix=false"]
    flags += ["--policy.distill.intermediate_jumps=0.5", "--policy.distill.teacher_velocity=conditional"]
    flags += ["--policy.distill.teacher_velocity_clamp=3", "--policy.distill.time_shift=2"]
    checkpoint = run_tiny_lerobot_train(student, data, tmp_path / "run", 2, 4, *flags)
    saved = json.loads((checkpoint / "config.json").read_text())
    expected = DistillSettings(
        target_steps=(2, 4),
        freeze_prefix=False,
        intermediate_jumps=0.5,
        teacher_velocity="conditional",
        teacher_velocity_clamp=3.0,
        time_shift=2.0,
    )
    assert saved["distill"] == json.loads(json.dumps(asdict(expected)))
    assert (saved["distill_steps"], saved["steps_distilled"], saved["distilled"]) == (2, 2, True)
    before, after = load_file(student / "model.safetensors"), load_file(checkpoint / "model.safetensors")
    vlm = [name for name in before if ".vlm." in name and not torch.equal(before[name], after[name])]
    assert vlm, "the prefix trained"
    # a resumed run goes on counting from its checkpoint's config (where a schedule's stage is read)
    lerobot_train = str(Path(sys.executable).with_name("lerobot-train"))
    resumed = [f"--config_path={checkpoint / 'train_config.json'}", "--resume=true", "--steps=3", "--save_freq=3"]
    run_checked([lerobot_train, *resumed], {"HF_HUB_OFFLINE": "1"})
    last = tmp_path / "run" / "checkpoints" / "last" / "pretrained_model"
    assert json.loads((last / "config.json").read_text())["steps_distilled"] == 3

    refused = subprocess.run(
        [lerobot_train, f"--policy.path={student}", "--dataset.repo_id=local/tiny", f"--dataset.root={data}"]
        + [f"--output_dir={tmp_path / 'refused'}", "--policy.distill.alpha=2"],
        capture_output=True,
        text=True,
        env={**os.environ, "HF_HUB_OFFLINE": "1"},
        timeout=600,
    )
    assert refused.returncode != 0 and "alpha must be in [0, 1], got 2.0" in refused.stderr, refused.stderr[-2000:]
    assert not (tmp_path / "refused" / "checkpoints").exists()


def _held_out_distances(root: Path, checkpoint: Path) -> dict[str, float]:
    """Mean squared distances on a dataset neither run saw, from the same noise: the checkpoint's one jump and the
    teacher's naive step, each to the teacher's 10-step actions."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset
    from lerobot.policies.factory import make_pre_post_processors
    from torch.utils.data import default_collate

    from snapflow.adapters.lerobot import load_pretrained_policy, wrap_policy
    from snapflow.adapters.lerobot.plugin import student_policy

    student = student_policy("smolvla").from_pretrained(checkpoint).snapflow
    teacher = wrap_policy(load_pretrained_policy(str(root / "teacher" / "lerobot_policy")))
    preprocessor, _ = make_pre_post_processors(student.policy.config, pretrained_path=str(checkpoint))
    held_out = LeRobotDataset("local/held", root=root / "held")
    batch = preprocessor(default_collate([held_out[index] for index in range(len(held_out))]))
    noise = torch.randn(len(held_out), 4, 4, generator=torch.Generator().manual_seed(0))
    actions = {
        name: sample_actions(policy, batch, noise, SamplingMode.parse(mode))
        for name, policy, mode in [
            ("teacher", teacher, "teacher-10"),
            ("naive", teacher, "naive-1"),
            ("snapflow", student, "snapflow-1"),
        ]
    }
    return {name: (actions[name] - actions["teacher"]).pow(2).mean().item() for name in ("naive", "snapflow")}


@pytest.mark.slow
@PLUGINS
def test_lerobot_train_on_a_student_type_distils_a_tiny_smolvla(tmp_path):
    from snapflow.training.config import TrainConfig
    from snapflow.training.lerobot import train_lerobot_teacher
    from snapflow.training.lerobot_student import write_student
    from tests.lerobot_tiny import write_tiny_dataset

    data = write_tiny_dataset(tmp_path / "data", episodes=6, frames=16, bimodal=True)
    write_tiny_dataset(tmp_path / "held", repo_id="local/held", episodes=2, frames=16, bimodal=True, seed=1)
    training = TrainConfig(steps=300, batch_size=16, learning_rate=1e-3, warmup_steps=20, checkpoint_every=1000)
    train_lerobot_teacher("smolvla", data, "local/tiny", tmp_path / "teacher", training, chunk_size=4, val_fraction=0.0)
    student = write_student(str(tmp_path / "teacher" / "lerobot_policy"), tmp_path / "student")
    steps = 200
    checkpoint = run_tiny_lerobot_train(
        student,
        data,
        tmp_path / "run",
        steps,
        16,
        "--policy.optimizer_lr=1e-3",
        "--policy.scheduler_warmup_steps=20",
        f"--policy.scheduler_decay_steps={steps}",
    )
    assert json.loads((checkpoint / "config.json").read_text())["distilled"] is True
    distances = _held_out_distances(tmp_path, checkpoint)
    assert distances["snapflow"] < 0.85 * distances["naive"], distances

    # lerobot-train writes no snapflow.json: snapflow's own tools open the checkpoint as the distilled student
    from snapflow.flow.modes import SNAPFLOW_1
    from snapflow.sources import open_policy

    opened = open_policy(checkpoint)
    assert opened.distilled and opened.policy_type == "snapflow_smolvla"
    opened.check_mode(SNAPFLOW_1)
    assert not opened.policy.policy.model.target_time_embedding.linear_out.weight.eq(0).all(), "phi_s was loaded"


def test_a_teacher_trained_with_a_weight_average_exports_the_average(tmp_path):
    """As a built-in run's checkpoints hold it, the average is the policy: the exported folder holds the weights the
    last checkpoint saved as its policy, not the raw trained ones beside them."""
    from safetensors.torch import load_file

    from snapflow.policies.checkpoint import resolve_checkpoint
    from snapflow.training.checkpoint import TRAINING_WEIGHTS
    from snapflow.training.config import TrainConfig
    from snapflow.training.lerobot import train_lerobot_teacher
    from tests.lerobot_tiny import write_tiny_dataset

    data = write_tiny_dataset(tmp_path / "data", episodes=2, frames=8)
    training = TrainConfig(steps=4, batch_size=4, learning_rate=1e-3, warmup_steps=1, checkpoint_every=4, ema_decay=0.5)
    train_lerobot_teacher("smolvla", data, "local/tiny", tmp_path / "teacher", training, chunk_size=4, val_fraction=0.0)
    checkpoint = resolve_checkpoint(tmp_path / "teacher")
    average, raw = load_file(checkpoint / "policy.safetensors"), load_file(checkpoint / TRAINING_WEIGHTS)
    exported = load_file(tmp_path / "teacher" / "lerobot_policy" / "model.safetensors")
    name = "model.action_out_proj.weight"
    assert not torch.equal(average[f"policy.{name}"], raw[f"policy.{name}"])
    assert all(torch.equal(tensor, average[f"policy.{key}"]) for key, tensor in exported.items())


@pytest.mark.skipif(
    Version(version("lerobot")) < Version(XVLAFlowPolicy.minimum_lerobot),
    reason=f"snapflow's X-VLA adapter needs lerobot >= {XVLAFlowPolicy.minimum_lerobot}",
)
def test_snapflow_train_fits_an_xvla_from_scratch_whose_folder_opens_anywhere(tmp_path):
    """``snapflow train --policy-type xvla --dataset``, as a user types it: an X-VLA over a Florence-2 at the tiny
    SmolVLM's widths learns the tiny dataset (its flow-matching loss over steps 51-100 under 0.7 of steps 1-50'), and its exported folder, moved
    away from the run that wrote it, opens and samples through its own processors (its tokenizer kept inside)."""
    import shutil

    import numpy as np

    from snapflow.flow.modes import NAIVE_1
    from snapflow.sources import open_policy
    from tests.lerobot_tiny import write_tiny_dataset

    data = write_tiny_dataset(tmp_path / "data", episodes=2, frames=8)
    run = tmp_path / "teacher"
    flags = ["--steps", "100", "--batch-size", "8", "--learning-rate", "1e-3"]
    command = ["snapflow", "train", "--policy-type", "xvla", "--dataset", str(data), "--output", str(run), *flags]
    command += ["--smolvlm", "tiny", "--chunk-length", "4", "--val-fraction", "0", "--no-progress", "--threads", "1"]
    finished = subprocess.run(command, capture_output=True, text=True, timeout=600, env={**os.environ, "CI": "true"})
    assert finished.returncode == 0, finished.stderr[-3000:]
    assert "xvla teacher trained to step 100" in finished.stdout
    losses = [row["loss"] for row in json.loads((run / "history.json").read_text())["history"]]
    assert len(losses) == 2 and losses[1] < 0.7 * losses[0], losses  # steps 1-50, then 51-100

    moved = shutil.copytree(run / "lerobot_policy", tmp_path / "elsewhere" / "policy")
    shutil.rmtree(run)  # the SmolVLM folder the run wrote is gone: the copy carries its own
    assert json.loads((moved / "config.json").read_text())["tokenizer_name"] == "smolvlm"
    opened = open_policy(moved)
    processor = opened.processor
    size = processor.image_size
    frame = np.full((1, size, size, 3), 128, dtype=np.uint8)
    observation = processor.observation(np.zeros((1, processor.state_dim), np.float32), ["reach the block"], frame)
    with torch.no_grad():
        chunk = sample_actions(opened.policy.eval(), observation, torch.randn(1, *opened.policy.action_shape), NAIVE_1)
    assert chunk.shape == (1, *opened.policy.action_shape) and torch.isfinite(chunk).all()
