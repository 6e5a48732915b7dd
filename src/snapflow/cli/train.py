"""``snapflow train``: a flow-matching teacher, a built-in policy on demonstrations or, from scratch on a
LeRobotDataset, a LeRobot type declared ``trains_from_scratch`` (SmolVLA, X-VLA)."""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path
from typing import Any

from snapflow.adapters.lerobot_config import SMOLVLM_SIZES
from snapflow.adapters.lerobot_types import lerobot_teachers
from snapflow.cli.common import (
    COUNT,
    SHARE,
    add_command,
    add_name_value_option,
    add_training_options,
    check_writable,
    given,
    training_interrupted,
    training_overrides,
)
from snapflow.errors import InvalidInputError
from snapflow.policies.factory import POLICIES
from snapflow.training.config import TEACHER_TRAINING, VAL_FRACTION, TrainConfig


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
    policy_types = [*POLICIES, *lerobot_teachers()]
    parser.add_argument(
        "--policy-type",
        choices=policy_types,
        default=next(iter(POLICIES)),
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
        default="small",
        help="a LeRobot type: the size of its VLM (SmolVLA's SmolVLM; X-VLA's Florence-2 at the same widths)",
    )
    parser.add_argument(
        "--n-action-steps", type=COUNT, default=4, help="a LeRobot type: actions LeRobot's select_action runs per chunk"
    )
    parser.add_argument(
        "--chunk-length", type=COUNT, help="actions per predicted chunk (default: the policy's; a LeRobot type 8)"
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
        "--val-fraction",
        type=_validation_share,
        default=VAL_FRACTION,
        help="share of each task's episodes held out, in [0, 1)",
    )


def run(args: argparse.Namespace) -> int:
    if (args.policy_type in lerobot_teachers()) != bool(args.dataset) or bool(args.data) == bool(args.dataset):
        raise InvalidInputError(
            f"give --data with a built-in policy ({', '.join(POLICIES)}) or --dataset with --policy-type "
            f"{' / '.join(lerobot_teachers())} (a LeRobotDataset)"
        )
    if args.dataset and args.policy_option:
        raise InvalidInputError(
            "--policy-option sets a built-in policy's configuration; it does not apply to --dataset"
        )
    check_writable(args.output)
    config = replace(TEACHER_TRAINING, **given(training_overrides(args)))
    if args.dataset:
        return _train_lerobot(args, config)
    from snapflow.data.demonstrations import Demonstrations
    from snapflow.training.stages import policy_config_for, train_teacher

    overrides = dict(args.policy_option or ()) | given(
        {"chunk_length": args.chunk_length, "image_size": args.image_size, "use_image": args.use_image or None}
    )
    policy = policy_config_for(args.policy_type, Demonstrations.load(args.data), args.state_dim, **overrides)
    state = train_teacher(
        args.data,
        args.output,
        policy,
        config,
        args.val_fraction,
        args.resume,
        not args.no_progress,
        keep_progress=args.keep_progress,
    )
    print(f"teacher trained to step {state['step']} in {state['wall_time_s']:.0f} s; checkpoints in {args.output}")
    return 0


def _train_lerobot(args: argparse.Namespace, config: TrainConfig) -> int:
    from snapflow.adapters.hub import dataset_source

    dataset_root, repo_id = dataset_source(args.dataset, args.repo_id)  # a mistyped root is named before LeRobot loads
    from snapflow.sources import LEROBOT_EXPORT_DIRECTORY
    from snapflow.training.lerobot import train_lerobot_teacher

    size = SMOLVLM_SIZES[args.smolvlm]
    if args.image_size:
        size = replace(size, image_size=args.image_size)
    state = train_lerobot_teacher(
        args.policy_type,
        dataset_root,
        repo_id,
        args.output,
        config,
        size,
        n_action_steps=args.n_action_steps,
        val_fraction=args.val_fraction,
        resume=args.resume,
        progress=not args.no_progress,
        keep_progress=args.keep_progress,
        **given({"chunk_size": args.chunk_length}),
    )
    print(
        f"{args.policy_type} teacher trained to step {state['step']} in {state['wall_time_s']:.0f} s; "
        f"LeRobot policy in {Path(args.output) / LEROBOT_EXPORT_DIRECTORY}"
    )
    return 0
