"""``snapflow bench-targets``: seconds per distillation step of each SnapFlow target on a built-in teacher."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from snapflow.cli.common import (
    COUNT,
    NON_NEGATIVE_COUNT,
    add_command,
    add_output,
    add_target_options,
    check_writable,
    nothing_written,
)


def add_parser(subparsers: Any) -> None:
    parser = add_command(
        subparsers,
        "bench-targets",
        "seconds per distillation step of each SnapFlow target (built-in policy)",
        run,
        nothing_written,
    )
    parser.add_argument("--teacher", required=True, help="teacher run or checkpoint directory (built-in policy)")
    parser.add_argument("--data", required=True, help="its demonstrations")
    add_target_options(parser, ("euler:2", "euler:4", "euler:8", "bootstrap:8"))
    parser.add_argument("--batch-size", type=COUNT, default=64, help="training pairs per timed step")
    parser.add_argument("--warmup", type=NON_NEGATIVE_COUNT, default=5, help="untimed steps of each target first")
    parser.add_argument("--repeats", type=COUNT, default=30, help="timed steps of each target")
    add_output(parser, "outputs/bench-targets", "where training_cost.json and .md go")


def run(args: argparse.Namespace) -> int:
    check_writable(args.output)
    from snapflow.benchmark.training_cost import checkpoint_training_cost, markdown_training_cost, write_training_cost

    result = checkpoint_training_cost(args.teacher, args.data, args.targets, args.batch_size, args.warmup, args.repeats)
    write_training_cost(result, args.output)
    print(markdown_training_cost(result))
    print(f"wrote training_cost.json and training_cost.md to {Path(args.output)}")
    return 0
