"""The command line's layout: one module per sub-command, its flags beside its run, listed in a fixed order; and
train's policy flag, renamed from a path-like name to what it takes."""

from __future__ import annotations

import argparse

from snapflow.cli import COMMANDS, build_parser


def _commands() -> dict[str, argparse.ArgumentParser]:
    parser = build_parser()
    return next(action for action in parser._actions if isinstance(action, argparse._SubParsersAction)).choices


def test_each_sub_command_is_one_module_that_declares_its_flags_and_runs_them():
    commands = _commands()
    assert list(commands) == [
        *("toy", "toy-compare", "collect", "experts", "train", "distill", "eval", "diagnose"),
        *("bench", "export", "bench-targets", "sweep", "demo"),
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
