"""``snapflow sweep``: sweep configs (seeds, ablations, baselines) run as cached jobs, then their results."""

from __future__ import annotations

import argparse
from typing import Any

from snapflow.cli.common import COUNT, add_command, runs_kept


def add_parser(subparsers: Any) -> None:
    parser = add_command(
        subparsers, "sweep", "run sweep configs (seeds, ablations, baselines) and write their results", run, runs_kept
    )
    parser.add_argument("configs", nargs="+", help="sweep TOML files, e.g. configs/sweeps/mt10-state.toml")
    parser.add_argument(
        "--workers",
        type=COUNT,
        default=1,
        help="jobs run side by side, each on --threads torch threads (default: cores / workers)",
    )
    parser.add_argument(
        "--document",
        help="also write the tables between their markers in this Markdown file (e.g. docs/results/metaworld.md)",
    )
    parser.add_argument("--report-only", action="store_true", help="only rebuild the results from finished runs")
    parser.add_argument(
        "--status",
        action="store_true",
        help="run nothing: print each job as done, kept (in the committed records), running or missing, and the "
        "machine time left, estimated from the measured times of finished jobs of each kind (on --workers)",
    )
    parser.add_argument(
        "--tables",
        type=lambda text: text.split(","),
        help="comma-separated: run and rebuild only these tables; the others keep their results in results.json "
        "(default: every table)",
    )


def run(args: argparse.Namespace) -> int:
    from snapflow.jobs.sweep import load_sweep, run_sweeps, write_results

    configs = [load_sweep(path) for path in args.configs]
    for config in configs:
        config.table_names(args.tables)  # a mistyped table is refused before anything runs
    if args.status:
        from snapflow.jobs.sweep.status import format_status, sweep_status

        for config in configs:
            print(format_status(config, sweep_status(config.only(args.tables)), args.workers))
        return 0
    if not args.report_only:
        run_sweeps([config.only(args.tables) for config in configs], args.workers, not args.no_progress, args.threads)
    for config in configs:
        write_results(config, args.document, args.tables)
        print(f"{config.name}: wrote results.json, tables.md and PNG plots to {config.results_dir}")
    if args.document:
        print(f"updated the sweep tables in {args.document}")
    return 0
