"""The ``snapflow`` command line: one sub-command per job, each a thin shell over the Python API."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from snapflow.experiments.toy import ToyConfig
from snapflow.io import write_json


def _toy(args: argparse.Namespace) -> int:
    from snapflow.experiments.toy import plot_toy_result, run_toy_experiment

    config = ToyConfig(seed=args.seed, teacher_steps=args.teacher_steps, distill_steps=args.distill_steps)
    started = time.perf_counter()
    result = run_toy_experiment(config, progress=not args.no_progress)
    elapsed = time.perf_counter() - started

    naive = result.distances["naive-1"]
    rows = [("teacher 10-NFE", "teacher-10", 10), ("naive 1-NFE", "naive-1", 1), ("SnapFlow 1-NFE", "snapflow-1", 1)]
    print(f"\nConditional Gaussian mixture, seed {config.seed}: {config.eval_contexts} contexts x "
          f"{config.samples_per_context} samples, energy distance to exact samples (lower is better)\n")
    print("| sampler        | NFE | energy distance | / naive 1-NFE |")
    print("|----------------|-----|-----------------|---------------|")
    for label, key, nfe in rows:
        print(f"| {label:<14} | {nfe:>3} | {result.distances[key]:>15.4f} | {result.distances[key] / naive:>13.3f} |")
    print(f"\ntrained and evaluated in {elapsed:.1f} s")

    output = Path(args.output_dir)
    plot_toy_result(result, output / "toy_samples.png")
    write_json(output / "toy_results.json", {**result.to_dict(), "wall_time_s": round(elapsed, 2)})
    print(f"wrote {output / 'toy_samples.png'} and {output / 'toy_results.json'}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="snapflow", description=__doc__.split("\n")[0] if __doc__ else None)
    commands = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    toy = commands.add_parser("toy", help="distill a 2-D conditional mixture and compare 10-step, naive 1-step, SnapFlow 1-step")
    toy.add_argument("--seed", type=int, default=ToyConfig.seed)
    toy.add_argument("--teacher-steps", type=int, default=ToyConfig.teacher_steps, help="flow-matching training steps")
    toy.add_argument("--distill-steps", type=int, default=ToyConfig.distill_steps, help="SnapFlow distillation steps")
    toy.add_argument("--output-dir", default="outputs/toy", help="where the PNG and JSON go")
    toy.add_argument("--no-progress", action="store_true", help="hide progress bars")
    toy.set_defaults(run=_toy)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return args.run(args)
    except (ValueError, TypeError, FileNotFoundError) as error:
        print(f"snapflow {args.command}: error: {error}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
