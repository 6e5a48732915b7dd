"""snapflow's CLI end to end on LeRobot policies built offline at tiny size: `snapflow distill` of a saved SmolVLA,
pi0 or pi0.5 on a local LeRobotDataset, and `snapflow eval` of the distilled SmolVLA in LeRobot's own Meta-World."""

from __future__ import annotations

import shutil

import pytest
import torch

pytest.importorskip("lerobot", reason="LeRobot is installed by the README's test command; this environment lacks it")


from snapflow.adapters.lerobot import load_distilled  # noqa: E402
from tests.lerobot_tiny import (  # noqa: E402
    PI_SKIP,
    build_tiny_pi,
    build_tiny_smolvla,
    tiny_pi_configs,
)


def _distill_arguments(tmp_path, dataset) -> list[str]:
    """``snapflow distill`` of the teacher saved at tmp_path/teacher on ``dataset``: three tiny steps into tmp_path/run."""
    return [
        "distill",
        "--policy",
        str(tmp_path / "teacher"),
        "--dataset",
        str(dataset),
        "--repo-id",
        "local/tiny",
        "--output",
        str(tmp_path / "run"),
        "--steps",
        "3",
        "--batch-size",
        "4",
        "--learning-rate",
        "1e-3",
        "--no-progress",
    ]


def _replaced(arguments: list[str], replacements: dict) -> list[str]:
    """``arguments`` with each one that is a key of ``replacements`` (a path or a string) replaced by its value."""
    by_text = {str(old): str(new) for old, new in replacements.items()}
    return [by_text.get(argument, argument) for argument in arguments]


@pytest.mark.slow
def test_cli_distills_a_saved_smolvla_on_a_local_lerobot_dataset(vlm_directory, tmp_path, capsys):
    from snapflow.cli import main
    from tests.lerobot_tiny import write_tiny_dataset

    dataset = write_tiny_dataset(tmp_path / "dataset")
    build_tiny_smolvla(vlm_directory).save_pretrained(tmp_path / "teacher")
    arguments = _distill_arguments(tmp_path, dataset)
    kept = ["--keep-progress", str(tmp_path / "kept")]
    assert main(arguments + kept) == 0
    assert (tmp_path / "run" / "checkpoints" / "step_0000003" / "policy.safetensors").is_file()
    distilled = load_distilled(tmp_path / "run" / "lerobot_policy")
    assert distilled.target_time_embedding.linear_out.weight.abs().sum() > 0, "phi_s must have trained"
    teacher = build_tiny_smolvla(vlm_directory)
    for name, parameter in teacher.model.vlm_with_expert.vlm.named_parameters():
        assert torch.equal(parameter, distilled.policy.model.vlm_with_expert.vlm.get_parameter(name)), (
            f"frozen {name} moved"
        )
    # the exported folder carries LeRobot's processors, its tokenizer inside: raw observations in, 1-NFE actions out
    from lerobot.policies.factory import make_pre_post_processors

    preprocessor, postprocessor = make_pre_post_processors(
        distilled.policy.config,
        pretrained_path=str(tmp_path / "run" / "lerobot_policy"),
        preprocessor_overrides={"device_processor": {"device": "cpu"}},
    )
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    frame = LeRobotDataset("local/tiny", root=dataset)[0]
    raw = {key: value[None] if torch.is_tensor(value) else [value] for key, value in frame.items()}
    actions = postprocessor(distilled.policy.predict_action_chunk(preprocessor(raw)))
    assert actions.shape == (1, 4, 4) and torch.isfinite(actions).all()

    assert main(arguments + ["--resume"]) == 0  # already at its last step: resumes and stops cleanly
    # on a machine with only the kept checkpoint, the finished run is continued at its last step: exported as it was
    moved = [str(tmp_path / "moved") if argument == str(tmp_path / "run") else argument for argument in arguments]
    capsys.readouterr()
    assert main(moved + kept + ["--resume"]) == 0
    out = capsys.readouterr().out
    assert "continuing from the one kept in" in out and "moved at step 3" in out, "no step trained again"
    again = load_distilled(tmp_path / "moved" / "lerobot_policy").state_dict()
    assert again.keys() == distilled.state_dict().keys()
    assert all(torch.equal(again[name], value) for name, value in distilled.state_dict().items())
    assert main(["distill", "--policy", "x", "--data", "y", "--output", str(tmp_path / "bad"), "--no-progress"]) == 2
    assert "either --teacher and --data" in capsys.readouterr().err
    # a policy whose state is shorter than the dataset's is named before any step (LeRobot would pad silently)
    build_tiny_smolvla(vlm_directory, state_dim=5).save_pretrained(tmp_path / "narrow")
    narrow = _replaced(
        arguments, {tmp_path / "teacher": tmp_path / "narrow", tmp_path / "run": tmp_path / "narrow_run"}
    )
    assert main(narrow) == 2
    assert "observation.state: the dataset has shape (6,), the policy expects (5,)" in capsys.readouterr().err
    assert not (tmp_path / "narrow_run" / "checkpoints").exists()
    # NaN in a dataset, which LeRobot records without complaint, is refused before any step
    nan_dataset = write_tiny_dataset(tmp_path / "nan_dataset", repo_id="local/nan", nan_at=17)
    poisoned = _replaced(
        arguments, {dataset: nan_dataset, "local/tiny": "local/nan", tmp_path / "run": tmp_path / "nan_run"}
    )
    assert main(poisoned) == 2
    assert "action holds NaN or inf (first at frame 17, dimension 1)" in capsys.readouterr().err
    assert not (tmp_path / "nan_run" / "checkpoints").exists()


@pytest.mark.slow
def test_cli_distills_a_smolvla_with_a_baseline_and_its_prefix_trained_as_lerobot_train_would(
    vlm_directory, tmp_path, capsys
):
    """The settings lerobot-train takes, snapflow's own trainer takes too: MeanFlow with every parameter trained; the
    exported student's config holds them (what lerobot-train on it goes on with). The no-phi_s ablation is refused
    by both, before anything loads."""
    import json

    from snapflow.cli import main
    from tests.lerobot_tiny import write_tiny_dataset

    dataset = write_tiny_dataset(tmp_path / "dataset")
    build_tiny_smolvla(vlm_directory).save_pretrained(tmp_path / "teacher")
    arguments = _distill_arguments(tmp_path, dataset)
    options = ["--method", "meanflow", "--objective-option", "adaptive_power=0.5", "--train-prefix"]
    assert main(arguments + options) == 0
    settings = json.loads((tmp_path / "run" / "lerobot_policy" / "config.json").read_text())["distill"]
    assert (settings["method"], settings["objective_options"], settings["freeze_prefix"]) == (
        "meanflow",
        {"adaptive_power": 0.5},
        False,
    )
    distilled, teacher = load_distilled(tmp_path / "run" / "lerobot_policy"), build_tiny_smolvla(vlm_directory)
    vlm = distilled.policy.model.vlm_with_expert.vlm
    assert any(
        not torch.equal(parameter, vlm.get_parameter(name))
        for name, parameter in teacher.model.vlm_with_expert.vlm.named_parameters()
    ), "the prefix trained"

    ablation = _replaced(arguments, {tmp_path / "run": tmp_path / "ablation"})
    assert main(ablation + ["--no-target-time"]) == 2
    assert "carries phi_s" in capsys.readouterr().err and not (tmp_path / "ablation").exists()


def test_distilling_into_an_output_another_process_holds_is_refused_before_anything_loads(tmp_path):
    from snapflow.reporting.locks import RunLockedError
    from snapflow.training.lerobot import distill_lerobot
    from tests.locking import held_by_another_process

    dataset = tmp_path / "dataset"
    (dataset / "meta").mkdir(parents=True)
    (dataset / "meta" / "info.json").write_text("{}")  # a dataset folder, checked first (a wrong one writes nothing)
    with held_by_another_process(tmp_path / "run", "snapflow distill") as holder:
        with pytest.raises(RunLockedError, match=rf"\(pid {holder.pid}, snapflow distill\)"):
            # the policy does not exist and the dataset is empty: the refusal comes before either loads
            distill_lerobot(str(tmp_path / "no-policy"), dataset, "local/none", tmp_path / "run")


@pytest.mark.slow
@PI_SKIP
@pytest.mark.parametrize("policy_type", ["pi0", "pi05"])
def test_cli_distills_a_saved_pi_policy_on_a_local_lerobot_dataset(policy_type, vlm_directory, tmp_path):
    from lerobot.datasets.lerobot_dataset import LeRobotDataset
    from lerobot.policies.factory import make_pre_post_processors

    from snapflow.cli import main
    from tests.lerobot_tiny import cache_as_hub_repo, write_tiny_dataset

    # LeRobot's pi processors load PaliGemma's tokenizer by hub id: the tiny one stands in for it, offline
    cache_as_hub_repo(vlm_directory, "google/paligemma-3b-pt-224")
    dataset = write_tiny_dataset(tmp_path / "dataset")
    build_tiny_pi(policy_type).save_pretrained(tmp_path / "teacher")
    with tiny_pi_configs(policy_type):
        assert main(_distill_arguments(tmp_path, dataset)) == 0
        distilled = load_distilled(tmp_path / "run" / "lerobot_policy")
    assert distilled.target_time_embedding.linear_out.weight.abs().sum() > 0, "phi_s must have trained"
    teacher = build_tiny_pi(policy_type)
    for name, parameter in teacher.model.paligemma_with_expert.paligemma.named_parameters():
        assert torch.equal(parameter, distilled.policy.model.paligemma_with_expert.paligemma.get_parameter(name)), (
            f"frozen {name} moved"
        )
    assert not torch.equal(teacher.model.action_out_proj.weight, distilled.policy.model.action_out_proj.weight)
    # the export carries LeRobot's processors: a raw dataset frame in, 1-NFE actions in the dataset's units out
    preprocessor, postprocessor = make_pre_post_processors(
        distilled.policy.config, pretrained_path=str(tmp_path / "run" / "lerobot_policy")
    )
    frame = LeRobotDataset("local/tiny", root=dataset)[0]
    raw = {key: value[None] if torch.is_tensor(value) else [value] for key, value in frame.items()}
    actions = postprocessor(distilled.policy.predict_action_chunk(preprocessor(raw)))
    assert actions.shape == (1, 4, 4) and torch.isfinite(actions).all()


@pytest.mark.slow
def test_cli_evaluates_a_distilled_smolvla_in_lerobots_own_metaworld(vlm_directory, tmp_path, capsys):
    import json

    from snapflow.cli import main
    from tests.lerobot_tiny import save_tiny_student

    directory = save_tiny_student(vlm_directory, tmp_path / "distilled")

    output = tmp_path / "eval"
    arguments = [
        "eval",
        "--lerobot-env",
        "metaworld",
        "--env-task",
        "reach-v3",
        "--policy",
        str(directory),
        "--episodes",
        "2",
        "--n-envs",
        "2",
        "--n-act",
        "2",
        "--modes",
        "snapflow-1,teacher-2",
        "--max-episode-steps",
        "12",
        "--output",
        str(output),
        "--no-progress",
    ]
    assert main(arguments) == 0
    report = json.loads((output / "report.json").read_text())
    assert report["policy_type"] == "smolvla" and report["n_action_steps"] == 2 and report["task"] == "reach-v3"
    assert list(report["modes"]) == ["snapflow-1", "teacher-2"]
    rewards = []
    for name, nfe in (("snapflow-1", 1), ("teacher-2", 2)):
        info = report["modes"][name]
        assert info["nfe"] == nfe and info["overall"]["n_episodes"] == 2 and 0 <= info["overall"]["pc_success"] <= 100
        assert (
            json.loads((output / name / "eval_info.json").read_text())["overall"] == info["overall"]
        )  # lerobot-eval's file
        rewards.append(info["overall"]["avg_sum_reward"])
    assert rewards[0] != rewards[1], "the two sampling modes must drive the robot differently"
    assert "| snapflow-1 | 1 |" in capsys.readouterr().out

    def changed(option: str, value: str) -> list[str]:
        changed = list(arguments)
        changed[changed.index(option) + 1] = value
        return changed

    assert main(changed("--lerobot-env", "nowhere")) == 2
    assert "unknown LeRobot environment 'nowhere'" in capsys.readouterr().err
    assert main(changed("--lerobot-env", "pusht")) == 2  # LeRobot's PushT package is not installed here
    assert (
        'LeRobot\'s pusht environment needs gym_pusht, which is not installed: pip install "lerobot[pusht]"'
        in capsys.readouterr().err
    )
    assert main(changed("--n-act", "9")) == 2  # more actions per chunk than the chunk holds
    assert "n_action_steps must be between 1" in capsys.readouterr().err

    # a student as lerobot-train leaves it (its config's own label, no snapflow.json) opens as every command opens it
    trained = tmp_path / "lerobot-train-student"
    shutil.copytree(directory, trained)
    (trained / "snapflow.json").unlink()
    quick = changed("--policy", str(trained))
    quick[quick.index("--modes") + 1] = "snapflow-1"
    quick[quick.index("--output") + 1] = str(tmp_path / "eval-trained")
    assert main(quick) == 0, capsys.readouterr().err
    assert list(json.loads((tmp_path / "eval-trained" / "report.json").read_text())["modes"]) == ["snapflow-1"]
    # never distilled: its one step would be the naive one, refused as such
    config = json.loads((trained / "config.json").read_text())
    (trained / "config.json").write_text(json.dumps({**config, "distilled": False}))
    assert main(quick) == 2
    assert (
        "is not SnapFlow-distilled (a flow-matching teacher): snapflow-1 would be the naive" in capsys.readouterr().err
    )
