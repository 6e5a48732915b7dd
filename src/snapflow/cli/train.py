"""``snapflow train``: a flow-matching teacher, a built-in policy on demonstrations or, from scratch on a
LeRobotDataset, a LeRobot type declared ``trains_from_scratch`` (SmolVLA, X-VLA)."""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path
from typing import Any

from snapflow.adapters.lerobot_config import SMOLVLM_SIZES, LeRobotSpec
from snapflow.adapters.lerobot_types import lerobot_teachers
from snapflow.cli.common import (
    COUNT,
    SHARE,
    add_command,
    add_name_value_option,
    add_training_options,
    argument_type,
    check_writable,
    given,
    print_trained,
    training_interrupted,
    training_overrides,
)
from snapflow.families import Progress, TeacherOptions, TeacherRun, family_of, teacher_types
from snapflow.flow.time_distribution import canonical_time_distribution, time_distribution_help
from snapflow.training.config import TEACHER_TRAINING, VAL_FRACTION


def _validation_share(text: str) -> float:
    value = SHARE(text)
    if value == 1:
        raise argparse.ArgumentTypeError("must be below 1 (some episodes must remain to train on), got 1")
    return value


class _DeprecatedPolicyFlag(argparse.Action):
    """``--policy``, train's old name of ``--policy-type`` (everywhere else ``--policy`` is a path): still read, with
    one line on stderr."""

    def __call__(
        self, parser: argparse.ArgumentParser, namespace: argparse.Namespace, values: Any, option_string: Any = None
    ) -> None:
        print(f"{parser.prog}: warning: --policy is deprecated for train; use --policy-type", file=sys.stderr)
        setattr(namespace, self.dest, values)


def add_parser(subparsers: Any) -> None:
    parser = add_command(
        subparsers,
        "train",
        "train a flow-matching teacher: a built-in one on demonstrations, or a LeRobot "
        f"{' / '.join(lerobot_teachers())} from scratch on a LeRobotDataset",
        run,
        training_interrupted,
    )
    add_training_options(parser, TEACHER_TRAINING, data_required=False)
    policy_types = teacher_types()
    parser.add_argument(
        "--policy-type",
        choices=policy_types,
        default=policy_types[0],  # the first built-in policy: the families list theirs first
        help=f"built-in policy (with --data), or a LeRobot type ({', '.join(lerobot_teachers())}): LeRobot's policy from "
        "scratch (with --dataset)",
    )
    parser.add_argument(
        "--policy", dest="policy_type", choices=policy_types, action=_DeprecatedPolicyFlag, help=argparse.SUPPRESS
    )
    parser.add_argument("--dataset", help="a LeRobot type: LeRobotDataset root directory on disk, or repo id")
    parser.add_argument("--repo-id", help="repo id of a dataset given as a directory (default: local/<folder name>)")
    parser.add_argument(
        "--smolvlm",
        choices=list(SMOLVLM_SIZES),
        help="a LeRobot type: the size of its VLM (SmolVLA's SmolVLM; X-VLA's Florence-2 at the same widths; "
        f"default: {LeRobotSpec.smolvlm})",
    )
    parser.add_argument(
        "--n-action-steps",
        type=COUNT,
        help=f"a LeRobot type: actions LeRobot's select_action runs per chunk (default: {LeRobotSpec.n_action_steps})",
    )
    parser.add_argument(
        "--chunk-length",
        type=COUNT,
        help=f"actions per predicted chunk (default: the policy's; a LeRobot type {LeRobotSpec.chunk_size})",
    )
    parser.add_argument("--use-image", action="store_true", help="minivla: read the demonstrations' camera images")
    parser.add_argument("--image-size", type=COUNT, help="minivla with --use-image, a LeRobot type: the images' size")
    parser.add_argument(
        "--state-dim", type=COUNT, help="read only the leading entries of the state (4: hand and gripper; default all)"
    )
    add_name_value_option(
        parser,
        "--policy-option",
        "a policy option",
        "image_encoder=conv",
        "a built-in policy's configuration field that no flag here sets, the value read as in TOML; repeatable "
        '(minivla: image_encoder=conv, extra_cameras=["image2"], image_downsample=2, ...: the fields of its config)',
    )
    parser.add_argument(
        "--time-distribution",
        type=argument_type(canonical_time_distribution),
        default=TEACHER_TRAINING.time_distribution,
        metavar="NAME[:VALUE]",
        help="a built-in teacher: the distribution of its flow-matching times, recorded in its checkpoint, whose "
        f"students' flow-matching rows draw it too: {time_distribution_help()} (default: %(default)s)",
    )
    parser.add_argument(
        "--val-fraction",
        type=_validation_share,
        default=VAL_FRACTION,
        help="share of each task's episodes held out, in [0, 1)",
    )


def run(args: argparse.Namespace) -> int:
    family = family_of(args.policy_type)  # the family's own flag names its source: --data or --dataset
    config = replace(TEACHER_TRAINING, **given(training_overrides(args)), time_distribution=args.time_distribution)
    family.check_teacher_training("--time-distribution", config)
    source = family.source(args.data, args.dataset, args.repo_id)
    check_writable(args.output)
    options = TeacherOptions(
        args.chunk_length,
        args.image_size,
        args.state_dim,
        args.use_image or None,
        args.smolvlm,
        args.n_action_steps,
        dict(args.policy_option) if args.policy_option else None,
    )
    spec = family.teacher_spec_for(args.policy_type, source, options)
    progress = Progress(args.resume, not args.no_progress, args.keep_progress)
    state = family.train_teacher(TeacherRun(spec, source, Path(args.output), config, args.val_fraction, progress))
    print_trained(
        f"{args.policy_type} teacher trained to step {state['step']} in {state['wall_time_s']:.0f} s; its policy in "
        f"{family.policy_path(Path(args.output))}"
    )
    return 0
