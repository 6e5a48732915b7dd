"""``snapflow experts``: the benchmark's scripted experts' own success per task (the ceiling)."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from snapflow.cli.common import COUNT, TASKS_HELP, add_command, add_output, check_writable, nothing_written, tasks
from snapflow.envs.base import SPLITS
from snapflow.envs.factory import BENCHMARKS, DEFAULT_BENCHMARK, make_benchmark


def add_parser(subparsers: Any) -> None:
    parser = add_command(
        subparsers, "experts", "the benchmark's scripted experts' success per task", run, nothing_written
    )
    parser.add_argument("--env", choices=list(BENCHMARKS), default=DEFAULT_BENCHMARK, help="benchmark")
    parser.add_argument("--tasks", help=TASKS_HELP)
    parser.add_argument("--split", choices=list(SPLITS), default="eval", help="whose variations the experts run on")
    parser.add_argument("--episodes", type=COUNT, default=50, help="episodes per task (one per variation)")
    parser.add_argument("--workers", type=COUNT, default=1, help="tasks run side by side, one process each")
    add_output(parser, "outputs/experts", "where experts.json and experts.md go")


def run(args: argparse.Namespace) -> int:
    chosen = tasks(args.env, args.tasks)
    check_writable(args.output)
    from snapflow.evaluation.experts import EXPERTS_MD, run_experts

    report = run_experts(
        make_benchmark(args.env), chosen, args.output, args.split, args.episodes, not args.no_progress, args.workers
    )
    mean = report["tasks"]["mean"]
    print(
        f"scripted experts: {100 * mean['success_rate']:.1f}% mean success over {len(chosen)} task(s) "
        f"({mean['successes']} / {mean['episodes']} episodes); per task in {Path(args.output) / EXPERTS_MD}"
    )
    return 0
