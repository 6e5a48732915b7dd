"""``snapflow bench``: batch-1 latency of a policy or an architecture at NFE 10, 5, 2, 1, its throughput, and the
cost of its distillation step."""

from __future__ import annotations

import argparse
from typing import Any

from snapflow.benchmark.architectures import architectures
from snapflow.cli.common import (
    COUNT,
    NON_NEGATIVE_COUNT,
    add_command,
    add_fast_path,
    add_output,
    check_writable,
    nothing_written,
)


def _counts(text: str) -> tuple[int, ...]:
    """A comma-separated list of counts, e.g. batch sizes ``1,8,32``."""
    return tuple(COUNT(part) for part in text.split(","))


def add_parser(subparsers: Any) -> None:
    parser = add_command(
        subparsers,
        "bench",
        "batch-1 latency at NFE 10, 5, 2, 1: prefix, denoising, end-to-end, speedups",
        run,
        nothing_written,
    )
    subject = parser.add_mutually_exclusive_group(required=True)
    subject.add_argument(
        "--policy", help="built-in checkpoint or run directory, distilled LeRobot folder, or LeRobot hub id / folder"
    )
    subject.add_argument(
        "--architecture", choices=architectures(), help="random weights at full size (minivla: the demo's policy)"
    )
    parser.add_argument(
        "--vlm", help="smolvla: folder (or hub id) of its VLM's config and processor (no weights are loaded)"
    )
    parser.add_argument("--device", help="cpu, cuda, cuda:1, ... (default: cuda when available)")
    parser.add_argument(
        "--dtype", choices=["float32", "bfloat16", "float16"], default="float32", help="weights and activations"
    )
    add_fast_path(parser, "the policy is timed in")
    parser.add_argument("--warmup", type=NON_NEGATIVE_COUNT, default=10, help="untimed calls of each quantity first")
    parser.add_argument("--repeats", type=COUNT, default=50, help="timed calls of each quantity, round-robin")
    parser.add_argument("--no-profile", action="store_true", help="skip the torch.profiler table of the 1-NFE path")
    parser.add_argument(
        "--distill-batch-sizes",
        type=_counts,
        help="also time a distillation step (the paper's objective, AdamW on the expert) and its peak memory at "
        "these batch sizes, e.g. 4,32",
    )
    parser.add_argument(
        "--vision-dtype",
        choices=["bfloat16"],
        help="pi0 / pi0.5: run the vision tower in this dtype (LeRobot keeps it in float32); reports how far actions move",
    )
    parser.add_argument(
        "--tf32",
        action="store_true",
        help="float32 matrix products in TF32 where the GPU has it (off in LeRobot); reports how far actions move",
    )
    parser.add_argument(
        "--batch-sizes",
        type=_counts,
        default=(1, 8, 32),
        help="throughput of the 10-step teacher and the one-step mode at these batch sizes (comma-separated)",
    )
    add_output(parser, "outputs/bench", "where bench.json, bench.md and the plot go")


def run(args: argparse.Namespace) -> int:
    check_writable(args.output)
    import torch

    from snapflow.benchmark.bench import run_bench, vision_in_bfloat16
    from snapflow.benchmark.report import markdown_bench, write_bench
    from snapflow.benchmark.subjects import make_subject

    device = torch.device(args.device or ("cuda" if torch.cuda.is_available() else "cpu"))
    dtype = {"float32": torch.float32, "bfloat16": torch.bfloat16, "float16": torch.float16}[args.dtype]
    subject = make_subject(args.policy, args.architecture, device, dtype, args.vlm)
    vision_difference = vision_in_bfloat16(subject) if args.vision_dtype else None
    distill_step = None
    if args.distill_batch_sizes:  # first, in place: before a fast path changes the policy
        from snapflow.benchmark.training_cost import distillation_step_cost

        distill_step = distillation_step_cost(
            subject.policy, subject.observation, subject.noise, args.distill_batch_sizes, subject.time_sampler
        )
    report = run_bench(
        subject,
        args.warmup,
        args.repeats,
        args.fast_path,
        profile=not args.no_profile,
        batch_sizes=args.batch_sizes,
        tf32=args.tf32,
    )
    report.distill_step, report.vision_bfloat16_difference = distill_step, vision_difference
    write_bench(report, args.output)
    print(markdown_bench(report))
    print(f"wrote bench.json, bench.md, latency.png{'' if args.no_profile else ' and profile.txt'} to {args.output}")
    return 0
