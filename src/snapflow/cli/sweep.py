"""``snapflow sweep``: sweep configs (seeds, ablations, baselines) run as cached jobs, then their results."""

from __future__ import annotations

import argparse
from typing import Any

from snapflow.cli.common import COUNT, NON_NEGATIVE, POSITIVE, add_command, runs_kept
from snapflow.errors import InvalidInputError
from snapflow.jobs.backends import BACKENDS, open_backend

RAY_OPTIONS = ("address", "gpus_per_job", "memory_per_job")  # --backend ray's own flags


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
        help="run nothing: print each job as done, kept (in the committed records), running or missing, how far an "
        "unfinished one has come (episodes, steps), and the machine time left, estimated from the measured times of "
        "finished jobs of each kind (on --workers)",
    )
    parser.add_argument(
        "--backend",
        choices=BACKENDS,
        default=BACKENDS[0],
        help="where the jobs run: local, worker processes on this machine; ray, tasks on a Ray cluster (the ray "
        "extra), whose nodes all see the sweep's folders and the folder it runs from at the same paths",
    )
    parser.add_argument(
        "--address",
        help="--backend ray: the cluster's head, HOST:PORT as `ray start --head` printed it (default: RAY_ADDRESS, "
        "else a Ray started on this machine for the sweep)",
    )
    parser.add_argument(
        "--gpus-per-job",
        type=NON_NEGATIVE,
        help="--backend ray: GPUs each training or evaluation job reserves (default: 1 where the cluster has GPUs, "
        "else 0)",
    )
    parser.add_argument(
        "--memory-per-job",
        type=POSITIVE,
        metavar="GIB",
        help="--backend ray: GiB of memory each job reserves, so that a node takes no more jobs than it holds "
        "(default: none reserved)",
    )
    parser.add_argument(
        "--tables",
        type=lambda text: text.split(","),
        help="comma-separated: run and rebuild only these tables; the others keep their results in results.json "
        "(default: every table)",
    )


def run(args: argparse.Namespace) -> int:
    given = [f"--{name.replace('_', '-')}" for name in RAY_OPTIONS if getattr(args, name) is not None]
    if args.backend != "ray" and given:
        raise InvalidInputError(f"{', '.join(given)}: only for --backend ray")
    from snapflow.jobs.sweep import load_sweep, run_sweeps, write_results

    backend = None
    if not (args.status or args.report_only):  # Ray imported here: where it is missing, its extra is named
        memory = None if args.memory_per_job is None else int(args.memory_per_job * 2**30)
        backend = open_backend(args.backend, args.address, args.gpus_per_job, memory)
    configs = [load_sweep(path) for path in args.configs]
    for config in configs:
        config.table_names(args.tables)  # a mistyped table is refused before anything runs
    if args.status:
        from snapflow.jobs.sweep.status import format_status, sweep_status

        for config in configs:
            print(format_status(config, sweep_status(config.only(args.tables)), args.workers))
        return 0
    if not args.report_only:
        only = [config.only(args.tables) for config in configs]
        run_sweeps(only, args.workers, not args.no_progress, args.threads, backend)
    for config in configs:
        write_results(config, args.document, args.tables)
        print(f"{config.name}: wrote results.json, tables.md and PNG plots to {config.results_dir}")
    if args.document:
        print(f"updated the sweep tables in {args.document}")
    return 0
