"""``snapflow diagnose``: where a one-step student fails on a task, against its teacher and the scripted expert."""

from __future__ import annotations

import argparse
from typing import Any

from snapflow.cli.common import COUNT, NON_NEGATIVE_COUNT, add_command, add_output, check_writable, nothing_written
from snapflow.envs.factory import BENCHMARKS
from snapflow.evaluation.config import N_ACT


def add_parser(subparsers: Any) -> None:
    parser = add_command(
        subparsers,
        "diagnose",
        "where a one-step student fails on a task: distance to the scripted expert along the episodes, and every "
        "row's chunks at the failed moments against the nearest demonstration",
        run,
        nothing_written,
    )
    parser.add_argument("--teacher", required=True, help="the teacher's run or checkpoint directory")
    parser.add_argument("--student", required=True, help="the distilled student's run or checkpoint directory")
    parser.add_argument("--task", required=True, help="one task of the benchmark, e.g. peg-insert-side-v3")
    parser.add_argument("--env", choices=list(BENCHMARKS), help="benchmark (default: the student's)")
    parser.add_argument("--data", help="demonstrations (default: those the student was distilled on)")
    parser.add_argument("--episodes", type=COUNT, default=20, help="evaluation episodes of the task")
    parser.add_argument("--n-act", type=COUNT, default=N_ACT, help="actions executed per predicted chunk")
    parser.add_argument("--teacher-steps", type=COUNT, default=10, help="Euler steps of the teacher row")
    parser.add_argument("--seed", type=NON_NEGATIVE_COUNT, default=0, help="seed of the sampling noise")
    add_output(parser, "outputs/diagnosis", "folder for diagnosis.json, diagnosis.md and the PNGs")


def run(args: argparse.Namespace) -> int:
    check_writable(args.output)
    from snapflow.evaluation.diagnosis import diagnose_student
    from snapflow.evaluation.diagnosis_report import markdown_diagnosis, write_diagnosis
    from snapflow.sources import open_policy

    diagnosis = diagnose_student(
        open_policy(args.teacher),
        open_policy(args.student),
        args.task,
        args.episodes,
        args.n_act,
        args.teacher_steps,
        args.env,
        args.data,
        seed=args.seed,
        progress=not args.no_progress,
    )
    write_diagnosis(diagnosis, args.output)
    print(markdown_diagnosis(diagnosis))
    print(f"wrote diagnosis.json, diagnosis.md, phases.png and the chunk plots to {args.output}")
    return 0
