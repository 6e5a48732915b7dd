"""The command line's layout: one module per sub-command, its flags beside its run, listed in a fixed order; and
train's policy flag, renamed from a path-like name to what it takes, and its options of a policy's configuration."""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import pytest

from snapflow.adapters.lerobot_types import lerobot_loads_plugins
from snapflow.cli import COMMANDS, build_parser, command_parsers, main
from snapflow.data.demonstrations import Demonstrations, Episode
from snapflow.policies.checkpoint import load_policy


def _commands() -> dict[str, argparse.ArgumentParser]:
    return command_parsers(build_parser())


def test_each_sub_command_is_one_module_that_declares_its_flags_and_runs_them():
    commands = _commands()
    assert list(commands) == [
        *("toy", "toy-compare", "collect", "experts", "train", "distill", "eval", "diagnose"),
        *("bench", "export", "serve", "bench-targets", "sweep", "checkpoints", "demo"),
    ]
    for module, (name, parser) in zip(COMMANDS, commands.items(), strict=True):
        assert module.__name__ == f"snapflow.cli.{name.replace('-', '_')}"
        assert parser.get_default("run") is module.run


def test_train_takes_a_policy_type_and_its_old_flag_still_works_with_one_warning(capsys):
    parser = build_parser()
    train = ["train", "--data", "d", "--output", "o"]
    assert parser.parse_args(train).policy_type == "minivla"  # the first registered policy
    assert parser.parse_args([*train, "--policy-type", "mlp"]).policy_type == "mlp"
    assert capsys.readouterr().err == ""
    assert parser.parse_args([*train, "--policy", "mlp"]).policy_type == "mlp"
    assert capsys.readouterr().err == "snapflow train: warning: --policy is deprecated for train; use --policy-type\n"
    train_help = _commands()["train"].format_help()
    assert "--policy-type" in train_help and "--policy " not in train_help and "--policy\n" not in train_help


def _camera_demonstrations(directory: Path) -> Path:
    """Two short episodes with 16-px frames from two cameras, written as `snapflow collect` writes them."""
    generator = np.random.default_rng(0)
    steps = 12
    frames = {name: generator.integers(0, 256, (steps, 16, 16, 3), dtype=np.uint8) for name in ("image", "image2")}
    demonstrations = Demonstrations(
        states=generator.normal(size=(steps, 3)).astype(np.float32),
        actions=generator.normal(size=(steps, 2)).astype(np.float32),
        episode_index=np.repeat([0, 1], 6),
        episodes=[Episode("reach-v3", 0, 0, 6), Episode("reach-v3", 1, 6, 6)],
        instructions={"reach-v3": "reach"},
        images=frames["image"],
        extra_images={"image2": frames["image2"]},
    )
    return demonstrations.save(directory)


def test_train_sets_any_field_of_a_built_in_policy_s_configuration_by_policy_option(tmp_path, capsys):
    """The camera encoder of the LIBERO teacher is reachable from the command line: each `--policy-option` lands in
    the trained checkpoint's configuration, read as TOML (a list for a tuple field); a field the policy lacks, or a
    value of the wrong type, is refused in one line before training."""
    data = _camera_demonstrations(tmp_path / "data")
    train = ["train", "--data", str(data), "--steps", "1", "--batch-size", "2", "--chunk-length", "2", "--no-progress"]
    options = ["image_encoder=conv", "conv_width=8", "keypoints=4", 'extra_cameras=["image2"]', "image_downsample=2"]
    given = [argument for option in options for argument in ("--policy-option", option)]
    assert main([*train, "--output", str(tmp_path / "run"), "--use-image", "--image-size", "16", *given]) == 0
    config = load_policy(tmp_path / "run").processor.config
    assert (config.image_encoder, config.conv_width, config.keypoints, config.image_downsample) == ("conv", 8, 4, 2)
    assert tuple(config.extra_cameras) == ("image2",) and config.use_image and config.image_size == 16
    capsys.readouterr()

    for option, message in (
        ("no_such_field=1", "the minivla policy has no option no_such_field"),
        ("keypoints=four", "keypoints"),
    ):
        output = tmp_path / option.partition("=")[0]
        assert main([*train, "--output", str(output), "--policy-option", option]) != 0
        error = capsys.readouterr().err
        assert message in error and "Traceback" not in error and len(error.strip().splitlines()) == 1
        assert not (output / "checkpoints").exists()


@pytest.mark.lerobot
def test_serve_names_the_lerobot_it_needs_in_one_line_where_lerobot_is_older(capsys):
    pytest.importorskip("lerobot", reason="LeRobot is installed by the README's test command")
    if lerobot_loads_plugins():
        pytest.skip("this LeRobot serves: tests/adapters/test_lerobot_serve.py runs the server")
    assert main(["serve", "--port", "1"]) == 2
    error = capsys.readouterr().err
    assert "snapflow serve needs lerobot >= 0.5" in error and len(error.strip().splitlines()) == 1
