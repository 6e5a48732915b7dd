"""``snapflow toy-compare``: SnapFlow's one-step targets, named recipes and the biased one step on a toy shape, over
seeds."""

from __future__ import annotations

import argparse
import time
from typing import Any

from snapflow.cli.common import (
    COUNT,
    NON_NEGATIVE_COUNT,
    add_command,
    add_consistency_weight,
    add_output,
    add_target_options,
    check_writable,
    given,
    runs_kept,
)
from snapflow.cli.toy import add_step_options
from snapflow.jobs.toy_config import SHAPES, BiasedOneStep, RecipeOption, ToyConfig, toy_distill_settings
from snapflow.training.recipes import RECIPES


def add_parser(subparsers: Any) -> None:
    parser = add_command(
        subparsers, "toy-compare", "SnapFlow's one-step targets on the toy mixture, over seeds", run, runs_kept
    )
    add_target_options(parser, ("euler:2", "euler:4", "euler:8"))
    parser.add_argument(
        "--recipes",
        nargs="+",
        choices=list(RECIPES),
        default=[],
        help="named recipes to compare too, after the targets",
    )
    parser.add_argument(
        "--biased-one-step",
        action="store_true",
        help="a last row: the teacher fine-tuned on noise-biased times and sampled in one step (arXiv 2606.05737)",
    )
    parser.add_argument(
        "--shape",
        choices=SHAPES,
        default=ToyConfig.shape,
        help="the toy distribution: the six-mode mixture, or two concentric rings (held out from tuning)",
    )
    parser.add_argument("--seeds", nargs="+", type=NON_NEGATIVE_COUNT, default=[0, 1, 2], help="seeds of every run")
    parser.add_argument(
        "--step-repeats",
        type=NON_NEGATIVE_COUNT,
        default=0,
        help="rounds of the round-robin timing of every row's distillation step, for its cost relative to the first "
        "row's (0: none)",
    )
    add_step_options(parser)
    add_consistency_weight(parser, None, " (default: the recipe's)")
    parser.add_argument(
        "--workers",
        type=COUNT,
        default=1,
        help="runs in parallel, each on --threads torch threads (default: cores / workers)",
    )
    add_output(parser, "outputs/toy-compare", "where runs, JSON, table and PNG go (finished runs are reused)")


def run(args: argparse.Namespace) -> int:
    check_writable(args.output)
    from snapflow.jobs.toy_compare import compare_targets, markdown_comparison

    settings = toy_distill_settings(**given({"consistency_weight": args.consistency_weight}))
    base = ToyConfig(
        teacher_steps=args.teacher_steps, distill_steps=args.distill_steps, distill=settings, shape=args.shape
    )
    options = [*args.targets, *(RecipeOption(name) for name in args.recipes)]
    options += [BiasedOneStep()] if args.biased_one_step else []
    started = time.perf_counter()
    summary = compare_targets(
        options, args.seeds, base, args.output, args.workers, not args.no_progress, args.threads, args.step_repeats
    )
    print(markdown_comparison(summary))
    print(
        f"\ndone in {(time.perf_counter() - started) / 60:.1f} min; wrote comparison.json, comparison.md, "
        f"comparison.png and coverage.png to {args.output}"
    )
    return 0
