"""``snapflow toy``: the paper's story on a 2-D conditional mixture whose samples are exact."""

from __future__ import annotations

import argparse
import time
from pathlib import Path
from typing import Any

from snapflow.cli.common import (
    COUNT,
    NON_NEGATIVE_COUNT,
    add_command,
    add_objective_options,
    add_output,
    check_writable,
    given,
    nothing_written,
)
from snapflow.jobs.toy_config import SHAPES, ToyConfig, toy_distill_settings
from snapflow.reporting.files import write_json


def add_parser(subparsers: Any) -> None:
    parser = add_command(
        subparsers,
        "toy",
        "distill a 2-D conditional mixture and compare 10-step, naive 1-step, SnapFlow 1-step",
        run,
        nothing_written,
    )
    parser.add_argument(
        "--seed", type=NON_NEGATIVE_COUNT, default=ToyConfig.seed, help="seed of data, models and noise"
    )
    parser.add_argument(
        "--shape", choices=SHAPES, default=ToyConfig.shape, help="the toy distribution: the mixture, or two rings"
    )
    add_step_options(parser)
    add_objective_options(parser)
    add_output(parser, "outputs/toy", "where the PNG and JSON go")


def add_step_options(parser: argparse.ArgumentParser) -> None:
    """``--teacher-steps`` and ``--distill-steps``, ToyConfig's defaults (``toy-compare`` takes them too)."""
    parser.add_argument(
        "--teacher-steps", type=COUNT, default=ToyConfig.teacher_steps, help="flow-matching training steps"
    )
    parser.add_argument("--distill-steps", type=COUNT, default=ToyConfig.distill_steps, help="distillation steps")


def run(args: argparse.Namespace) -> int:
    check_writable(args.output)
    from snapflow.jobs.toy import markdown_toy, plot_toy_result, run_toy_experiment

    objective = {"method": args.method, "consistency_weight": args.consistency_weight, "target": args.target}
    settings = toy_distill_settings(**given({**objective, "target_steps": args.target_steps}))
    config = ToyConfig(
        seed=args.seed,
        teacher_steps=args.teacher_steps,
        distill_steps=args.distill_steps,
        distill=settings,
        shape=args.shape,
    )
    started = time.perf_counter()
    result = run_toy_experiment(config, progress=not args.no_progress)
    elapsed = time.perf_counter() - started

    print(f"\n{markdown_toy(result)}")
    print(f"\ntrained and evaluated in {elapsed:.1f} s ({1000 * result.distill_step_s:.1f} ms per distillation step)")

    output = Path(args.output)
    plot_toy_result(result, output / "toy_samples.png")
    write_json(output / "toy_results.json", {**result.to_dict(), "wall_time_s": round(elapsed, 2)})
    print(f"wrote {output / 'toy_samples.png'} and {output / 'toy_results.json'}")
    return 0
