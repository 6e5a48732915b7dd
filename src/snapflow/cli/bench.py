"""``snapflow bench``: batch-1 latency of a policy or an architecture at NFE 10, 5, 2, 1, its throughput, and the
cost of its distillation step."""

from __future__ import annotations

import argparse
import os
import tempfile
from pathlib import Path
from typing import Any

from snapflow.adapters.lerobot_config import SMOLVLM_SIZES
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
    vlm = parser.add_mutually_exclusive_group()
    vlm.add_argument(
        "--vlm", help="smolvla: folder (or hub id) of its VLM's config and processor (no weights are loaded)"
    )
    vlm.add_argument(
        "--smolvlm",
        choices=list(SMOLVLM_SIZES),
        help="smolvla: its VLM's config written locally at this size instead (full: SmolVLM2-500M's dimensions, "
        "SmolVLA's own; no hub)",
    )
    parser.add_argument(
        "--prompt-tokens",
        type=COUNT,
        help="a LeRobot policy's prompt: this many real tokens, the rest of its padded length padding (default: all "
        "real, the most a prefix costs)",
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
        "--compile-cache",
        metavar="DIR",
        help="torch's compile cache for the fast path ($TORCHINDUCTOR_CACHE_DIR; default: torch's, in the temporary "
        "directory): empty, the first chunk is timed from a cold start; filled by an earlier run, from a warm one",
    )
    parser.add_argument(
        "--batch-sizes",
        type=_counts,
        default=(1, 8, 32),
        help="throughput of the 10-step teacher and the one-step mode at these batch sizes (comma-separated)",
    )
    add_output(parser, "outputs/bench", "where bench.json, bench.md and the plot go")


def _written_smolvlm(size: str, folder: Path) -> str:
    """A SmolVLM config, processor and word-level tokenizer of size ``size`` written in ``folder``."""
    from snapflow.adapters.lerobot.smolvlm import words_of, write_smolvlm

    return str(write_smolvlm(folder, words_of(["pick up the object and place it in the basket"]), SMOLVLM_SIZES[size]))


def run(args: argparse.Namespace) -> int:
    check_writable(args.output)
    if args.compile_cache:  # before torch compiles anything: it reads the variable then
        os.environ["TORCHINDUCTOR_CACHE_DIR"] = str(Path(args.compile_cache).resolve())
    import torch

    from snapflow.benchmark.bench import run_bench
    from snapflow.benchmark.report import markdown_bench, write_bench
    from snapflow.benchmark.subjects import make_subject, with_prompt_tokens

    device = torch.device(args.device or ("cuda" if torch.cuda.is_available() else "cpu"))
    dtype = {"float32": torch.float32, "bfloat16": torch.bfloat16, "float16": torch.float16}[args.dtype]
    with tempfile.TemporaryDirectory() as scratch:
        vlm = _written_smolvlm(args.smolvlm, Path(scratch)) if args.smolvlm else args.vlm
        subject = make_subject(args.policy, args.architecture, device, dtype, vlm)
    if args.prompt_tokens:
        subject = with_prompt_tokens(subject, args.prompt_tokens)
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
    )
    report.distill_step = distill_step
    write_bench(report, args.output)
    print(markdown_bench(report))
    print(f"wrote bench.json, bench.md, latency.png{'' if args.no_profile else ' and profile.txt'} to {args.output}")
    return 0
