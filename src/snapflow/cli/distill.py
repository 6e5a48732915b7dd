"""``snapflow distill``: a teacher SnapFlow-distilled into a one-step student, a built-in policy on demonstrations or
a LeRobot policy of a declared type (``adapters/lerobot_types.py``) on a LeRobotDataset, from a named recipe that each
flag given overrides."""

from __future__ import annotations

import argparse
from dataclasses import fields
from pathlib import Path
from typing import Any

from snapflow.adapters.lerobot_types import LEROBOT_POLICY_TYPES
from snapflow.cli.common import (
    NON_NEGATIVE_COUNT,
    POSITIVE,
    RECIPE_SUMMARIES,
    SHARE,
    add_command,
    add_name_value_option,
    add_objective_options,
    add_training_options,
    check_writable,
    given,
    print_trained,
    training_interrupted,
    training_overrides,
)
from snapflow.errors import InvalidInputError
from snapflow.families import FAMILIES, PolicyFamily, Progress, StudentRun
from snapflow.objective.options import TEACHER_VELOCITIES
from snapflow.objective.registry import OBJECTIVES
from snapflow.training.config import TrainConfig
from snapflow.training.recipes import DEFAULT_RECIPE, LEROBOT_RECIPE, RECIPES, DistillSettings


def add_parser(subparsers: Any) -> None:
    parser = add_command(
        subparsers, "distill", "SnapFlow-distill a teacher into a 1-NFE student", run, training_interrupted
    )
    # no parser defaults: the recipe's, and a LeRobot policy trains with the paper's settings
    add_training_options(parser, None, data_required=False)
    parser.add_argument(
        "--recipe",
        choices=list(RECIPES),
        help="the student's settings, each overridden by the options below: "
        + RECIPE_SUMMARIES
        + f" (default: {DEFAULT_RECIPE} for a built-in teacher, {LEROBOT_RECIPE} for a LeRobot policy)",
    )
    parser.add_argument("--teacher", help="teacher run or checkpoint directory (built-in policy)")
    parser.add_argument(
        "--policy",
        help=f"LeRobot policy ({', '.join(LEROBOT_POLICY_TYPES)}): hub id or local pretrained directory",
    )
    parser.add_argument("--dataset", help="LeRobotDataset: root directory on disk, or repo id")
    parser.add_argument("--repo-id", help="repo id of a dataset given as a directory (default: local/<folder name>)")
    parser.add_argument(
        "--lerobot-train",
        action="store_true",
        help="with --policy and no --dataset: write the LeRobot policy as its SnapFlow student (phi_s at zero, these "
        "settings in its config, its processors) into --output, for LeRobot's own trainer to distil: lerobot-train "
        "--policy.path=OUTPUT --dataset.repo_id=... (training flags are lerobot-train's then)",
    )
    parser.add_argument("--alpha", type=SHARE, default=None, help="flow-matching share of each batch")
    parser.add_argument(
        "--clamp",
        type=POSITIVE,
        default=None,
        help="bound on the no-grad teacher velocities (default: the recipe's, none in both)",
    )
    parser.add_argument("--train-prefix", action="store_true", help="also train the prefix encoder (frozen by default)")
    parser.add_argument(
        "--shard",
        action="store_true",
        help="split the student's weights, gradients and optimizer state over the processes of the launch (torch's "
        "FSDP2), for a student that does not fit one device: accelerate launch --multi_gpu --num_processes N -m "
        "snapflow.cli distill ... --shard (or torchrun); not with --ema-decay or consistency distillation",
    )
    parser.add_argument(
        "--teacher-velocity",
        choices=TEACHER_VELOCITIES,
        default=None,
        help="snapflow's consistency target from the model's marginal velocity, or eps - a (ablation; default: the "
        "recipe's)",
    )
    parser.add_argument("--no-target-time", action="store_true", help="ablation: no target-time embedding phi_s")
    parser.add_argument(
        "--intermediate-jumps",
        type=SHARE,
        default=None,
        help="share of the one-step rows that jump between inner times t -> s instead of 1 -> 0 (default: the recipe's)",
    )
    parser.add_argument(
        "--time-shift",
        type=POSITIVE,
        default=None,
        help="push the flow-matching rows' times toward noise, t -> s t / (1 + (s - 1) t) (default 1: the policy's "
        "own); --alpha 1 --time-shift 4 fine-tunes without distilling, as arXiv 2606.05737 does (the result samples "
        "as naive or teacher-N)",
    )
    parser.add_argument(
        "--rtc-max-delay",
        type=NON_NEGATIVE_COUNT,
        default=None,
        help="train real-time chunking in: each row's first 0..N actions given as known, at time 0 (LeRobot's "
        "training-time RTC), so the jump continues a previous chunk's prefix (LeRobot's RTC mode 'trained'; SmolVLA); "
        "default 0: off",
    )
    add_objective_options(parser)
    settings_fields = {field.name for field in fields(DistillSettings)}
    own_options = {
        entry.name: [option for option in entry.options if option not in settings_fields]
        for entry in OBJECTIVES.values()
    }
    add_name_value_option(
        parser,
        "--objective-option",
        "an objective option",
        "adaptive_power=0.5",
        "an option of the chosen objective that no flag here sets, the value read as in TOML; repeatable ("
        + "; ".join(f"{name}: {', '.join(options)}" for name, options in own_options.items() if options)
        + ")",
    )


def run(args: argparse.Namespace) -> int:
    if args.lerobot_train:
        return _write_student(args)
    family = _family_of_flags(args)
    source = family.source(args.data, args.dataset, args.repo_id)  # a mistyped root is named before anything loads
    check_writable(args.output)
    train, settings = _student_settings(args, family)
    progress = Progress(args.resume, not args.no_progress, args.keep_progress)
    teacher = getattr(args, family.teacher_flag)
    run = StudentRun(teacher, source, Path(args.output), train, settings, progress=progress, shard=args.shard)
    state = family.distill(run)
    print_trained(
        f"SnapFlow student trained to step {state['step']} in {state['wall_time_s']:.0f} s; its policy in "
        f"{family.policy_path(Path(args.output))}"
    )
    return 0


def _family_of_flags(args: argparse.Namespace) -> PolicyFamily:
    """The family whose teacher and source flags were both given, and no other family's."""
    for family in FAMILIES:
        own = {family.teacher_flag, family.data_flag}
        others = {flag for other in FAMILIES for flag in (other.teacher_flag, other.data_flag)} - own
        if all(getattr(args, flag) for flag in own) and not any(getattr(args, flag) for flag in others):
            return family
    choices = [f"--{family.teacher_flag} and --{family.data_flag} (a {family.title} policy)" for family in FAMILIES]
    raise InvalidInputError(f"give either {' or '.join(choices)}")


def _write_student(args: argparse.Namespace) -> int:
    if not args.policy or args.dataset or args.teacher or args.data:
        raise InvalidInputError("--lerobot-train takes --policy and no dataset: lerobot-train reads the dataset")
    if args.keep_progress:
        raise InvalidInputError(
            "--lerobot-train writes no training run, so it keeps no progress: lerobot-train checkpoints"
        )
    if args.shard:
        raise InvalidInputError("--lerobot-train writes no training run, so it shards none: lerobot-train trains it")
    if given(training_overrides(args)):
        raise InvalidInputError(
            f"--lerobot-train writes no training run: give {', '.join(given(training_overrides(args)))} to "
            "lerobot-train (--steps, --batch_size, --policy.optimizer_lr, ...)"
        )
    check_writable(args.output)
    _, settings = _student_settings(args, next(family for family in FAMILIES if "lerobot-train" in family.trainers))
    from snapflow.training.lerobot_student import write_student

    output = write_student(args.policy, args.output, settings)
    print(
        f"wrote {args.policy} as its SnapFlow student in {output} (the teacher's weights, phi_s at zero, not distilled "
        f"yet); distil it with LeRobot's trainer: lerobot-train --policy.path={output} --dataset.repo_id=<dataset> "
        "--output_dir=<run>"
    )
    return 0


def _student_settings(args: argparse.Namespace, family: PolicyFamily) -> tuple[TrainConfig, DistillSettings]:
    """The student's recipe (``--recipe``, or its family's), each flag given overriding it."""
    overrides = {
        "alpha": args.alpha,
        "consistency_weight": args.consistency_weight,
        "teacher_velocity_clamp": args.clamp,
        "freeze_prefix": False if args.train_prefix else None,
        "method": args.method,
        "teacher_velocity": args.teacher_velocity,
        "target_time": False if args.no_target_time else None,
        "target": args.target,
        "target_steps": args.target_steps,
        "intermediate_jumps": args.intermediate_jumps,
        "time_shift": args.time_shift,
        "rtc_max_delay": args.rtc_max_delay,
        "objective_options": dict(args.objective_option) if args.objective_option else None,
    }
    return family.student_settings(args.recipe, given(training_overrides(args)), given(overrides))
