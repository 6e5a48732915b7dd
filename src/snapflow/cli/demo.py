"""``snapflow demo``: the README's main job, MT10 collect -> train -> distill -> eval into one table."""

from __future__ import annotations

import argparse
from typing import Any

from snapflow.cli.common import RECIPE_SUMMARIES, add_command, add_output, check_writable
from snapflow.training.recipes import DEFAULT_RECIPE, RECIPES


def add_parser(subparsers: Any) -> None:
    parser = add_command(
        subparsers, "demo", "MT10: collect -> train -> distill -> eval, one final table", run, _interrupted
    )
    parser.add_argument("--full", action="store_true", help="stronger, longer preset")
    parser.add_argument(
        "--recipe", choices=list(RECIPES), default=DEFAULT_RECIPE, help="the student's recipe: " + RECIPE_SUMMARIES
    )
    parser.add_argument(
        "--resume", action="store_true", help="continue an interrupted demo in the same output directory"
    )
    add_output(parser, "outputs/demo", "where the data, runs, report and plots go")


def run(args: argparse.Namespace) -> int:
    check_writable(args.output)
    from snapflow.evaluation.report import markdown_report
    from snapflow.jobs.demo import PRESETS, run_demo, with_recipe

    preset = PRESETS["full" if args.full else "fast"]
    report = run_demo(with_recipe(preset, args.recipe), args.output, not args.no_progress, args.resume)
    print(markdown_report(report))
    print(f"wrote report.json, report.md and PNG plots to {args.output}")
    return 0


def _interrupted(args: argparse.Namespace) -> str:
    return f"interrupted; finished stages and the last checkpoint are kept in {args.output}: continue with --resume"
