"""A LeRobot student's one distillation config: ``distill``, the ``DistillSettings`` that ``snapflow distill`` takes,
nested in its LeRobot config. Every setting goes through its ``config.json`` and LeRobot's own parser (flags
included), is checked as the config loads, and reaches the student's ``forward`` as snapflow's own objective; a
``config.json`` of the older flat form (``distill_*`` keys) still loads."""

from __future__ import annotations

import json
import re
from dataclasses import replace
from pathlib import Path

import pytest
import torch

pytest.importorskip("lerobot", reason="LeRobot is installed by the README's test command; this environment lacks it")

from snapflow.adapters.lerobot.registry import lerobot_time_sampler  # noqa: E402
from snapflow.errors import InvalidInputError  # noqa: E402
from snapflow.objective.settings import DistillSettings  # noqa: E402
from snapflow.policies.loaded import CheckpointError  # noqa: E402
from tests.lerobot_tiny import build_tiny_smolvla, tiny_batch  # noqa: E402

#: every setting off its default in one of them, each objective among them
EVERY_SETTING = {
    "bootstrap": DistillSettings(target="bootstrap", target_steps=4),
    "euler schedule": DistillSettings(
        target_steps=(2, 8),
        intermediate_jumps=0.5,
        teacher_velocity="conditional",
        teacher_velocity_clamp=3.0,
        time_shift=2.0,
        freeze_prefix=False,
    ),
    "meanflow": DistillSettings(method="meanflow", objective_options={"adaptive_power": 0.5}),
    "consistency distillation": DistillSettings(
        method="consistency-distillation", alpha=0.25, consistency_weight=3.0, objective_options={"num_intervals": 4}
    ),
}


def _saved(folder: Path, settings: DistillSettings | None = None) -> Path:
    """A SmolVLA student's config with ``settings`` written to ``folder`` as LeRobot writes it."""
    from snapflow.adapters.lerobot.plugin import student_config_class

    folder.mkdir()
    student_config_class("smolvla")(distill=settings or DistillSettings())._save_pretrained(folder)
    return folder


def _load(folder: Path, *flags: str):
    """The config LeRobot's own loader reads from ``folder`` (as ``lerobot-train --policy.path`` does), ``flags`` its
    ``--policy.*`` overrides without the prefix."""
    from lerobot.configs.policies import PreTrainedConfig

    return PreTrainedConfig.from_pretrained(folder, cli_overrides=list(flags))


@pytest.mark.parametrize("settings", EVERY_SETTING.values(), ids=EVERY_SETTING)
def test_every_setting_goes_through_a_students_config_json_and_lerobots_own_loader(settings, tmp_path):
    folder = _saved(tmp_path / "student", settings)
    saved = json.loads((folder / "config.json").read_text())
    assert saved["type"] == "snapflow_smolvla" and isinstance(saved["distill"], dict)
    assert not [key for key in saved if key.startswith("distill_") and key != "distill_steps"], "no flat key written"
    assert _load(folder).distill == settings


def test_flags_set_each_setting_and_the_settings_own_checks_refuse_a_bad_one(tmp_path):
    from snapflow.adapters.lerobot.checkpoint import load_student_config

    folder = _saved(tmp_path / "student")
    flags = ["--distill.target=bootstrap", "--distill.target_steps=4", "--distill.time_shift=2"]
    expected = DistillSettings(target="bootstrap", target_steps=4, time_shift=2.0, freeze_prefix=False)
    assert _load(folder, *flags, "--distill.freeze_prefix=false").distill == expected
    meanflow = _load(folder, "--distill.method=meanflow", '--distill.objective_options={"adaptive_power": 0.5}')
    assert meanflow.distill == EVERY_SETTING["meanflow"]
    assert _load(folder, "--distill.target_steps=[2,4,8]", "--distill_steps=30").distill_steps == 30

    refused = {
        "--distill.alpha=2": r"alpha must be in \[0, 1\], got 2",
        "--distill.target_time=false": r"carries phi_s .* \(target_time false\)",
        "--distill.target=shortcut": "unknown SnapFlow target 'shortcut'",
    }
    for flag, why in refused.items():
        with pytest.raises(Exception) as raised:  # LeRobot's parser (draccus) wraps the settings' own error
            _load(folder, flag)
        assert isinstance(raised.value.__cause__, InvalidInputError), flag
        assert re.search(why, str(raised.value.__cause__)), (flag, str(raised.value.__cause__))
    with pytest.raises(Exception) as raised:
        _load(folder, "--distill.method=meanflow", "--distill.target_steps=4")
    assert "target_steps is not an option of the meanflow objective" in str(raised.value.__cause__)

    # snapflow's own loader names a bad config.json in one line
    bad = json.loads((folder / "config.json").read_text())
    (folder / "config.json").write_text(json.dumps({**bad, "distill": {**bad["distill"], "alpha": 2}}))
    with pytest.raises(CheckpointError, match=r"config.json does not load: alpha must be in \[0, 1\], got 2"):
        load_student_config(folder)


def test_a_config_json_of_the_older_flat_form_loads_into_distill(tmp_path):
    """A student's ``config.json`` as snapflow wrote it before ``distill`` was nested: its five flat keys (the old
    field names), written by hand here, are read into ``distill``; a flag still sets a setting over them, and the
    config is written back in the nested form only."""
    from snapflow.adapters.lerobot.checkpoint import load_student_config

    folder = _saved(tmp_path / "student")
    config = json.loads((folder / "config.json").read_text())
    for new in ("distill", "distill_steps", "steps_distilled"):
        del config[new]
    config |= {
        "distill_alpha": 1.0,
        "distill_consistency_weight": 3.0,
        "distill_target_steps": 4,
        "distill_teacher_velocity_clamp": None,
        "distill_time_shift": 4.0,
    }
    (folder / "config.json").write_text(json.dumps(config))
    older = DistillSettings(alpha=1.0, consistency_weight=3.0, target_steps=4, time_shift=4.0)
    assert _load(folder).distill == older
    assert load_student_config(folder).distill == older
    assert _load(folder, "--distill.time_shift=2").distill == replace(older, time_shift=2.0), "the flag wins"
    assert _load(folder).distill_alpha is None, "read into distill, not kept"

    rewritten = tmp_path / "rewritten"
    rewritten.mkdir()
    _load(folder)._save_pretrained(rewritten)
    saved = json.loads((rewritten / "config.json").read_text())
    assert "distill_alpha" not in saved and saved["distill"]["alpha"] == 1.0
    assert _load(rewritten).distill == older

    config["distill_alpha"] = 2.0  # checked as the nested settings are
    (folder / "config.json").write_text(json.dumps(config))
    with pytest.raises(InvalidInputError, match=r"alpha must be in \[0, 1\], got 2"):
        _load(folder)


def _student(vlm_directory, settings: DistillSettings, **fields):
    from snapflow.adapters.lerobot.plugin import student_config, student_policy

    teacher = build_tiny_smolvla(vlm_directory)
    config = replace(student_config(teacher.config), distill=settings, **fields)
    student = student_policy("smolvla")(config)
    student.load_state_dict(teacher.state_dict(), strict=False)
    return student


@pytest.mark.parametrize("settings", EVERY_SETTING.values(), ids=EVERY_SETTING)
def test_every_setting_reaches_the_students_forward_as_snapflows_own_objective(settings, vlm_directory):
    """The loss ``lerobot-train`` steps on is the one ``snapflow distill`` builds from the same settings, at the
    stage of a schedule the step count gives (the second of two stages here, at step 2 of 4), on the parameters the
    settings train (every one where the prefix is not frozen)."""
    student = _student(vlm_directory, settings, distill_steps=4, steps_distilled=2)
    batch = tiny_batch(batch_size=6)
    loss, logs = student.forward(dict(batch), generator=torch.Generator().manual_seed(7))
    objective = settings.objective(lerobot_time_sampler(student.config))
    expected = objective(
        student.snapflow,
        dict(batch),
        student.snapflow.action_targets(batch),
        generator=torch.Generator().manual_seed(7),
        progress=0.5,
    )
    assert torch.equal(loss, expected.loss) and logs["consistency_loss"] == expected.consistency_loss.item()
    assert type(student.distillation_objective()) is type(objective)
    trained = {id(parameter) for parameter in student.parameters() if parameter.requires_grad}
    if settings.freeze_prefix:
        assert trained == {id(parameter) for parameter in student.snapflow.expert_parameters()}
    else:
        assert (
            trained == {id(parameter) for parameter in student.parameters()} == set(map(id, student.get_optim_params()))
        )
        loss.backward()
        assert any(parameter.grad is not None for parameter in student.model.vlm_with_expert.vlm.parameters())


def test_a_schedule_reads_its_stage_from_the_steps_update_counts(vlm_directory):
    student = _student(vlm_directory, DistillSettings(target_steps=(2, 8)))
    batch = tiny_batch()
    with pytest.raises(InvalidInputError, match="give lerobot-train its steps as --policy.distill_steps too"):
        student.forward(dict(batch))
    student.config.distill_steps = 2
    objective = student.distillation_objective()
    stages = []
    for _ in range(2):
        stages.append(objective.schedule(student.progress())["target_steps"])
        student.forward(dict(batch))[0].backward()
        student.update()
    assert stages == [2, 8] and student.config.steps_distilled == 2
    assert student.distillation_objective() is objective, "built once while the settings hold"
