"""``snapflow export``: a one-step student as one graph in an export format (ONNX), which eval and bench load."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from snapflow.cli.common import add_command, add_output, check_writable, nothing_written
from snapflow.inference.formats import EXPORT_FORMATS


def add_parser(subparsers: Any) -> None:
    parser = add_command(
        subparsers,
        "export",
        "export a one-step student as one ONNX graph (prefix and jump, no sampling loop)",
        run,
        nothing_written,
    )
    parser.add_argument(
        "--policy", required=True, help="student checkpoint or run directory, or distilled LeRobot folder"
    )
    parser.add_argument("--format", choices=list(EXPORT_FORMATS), default="onnx", help="the exported format")
    add_output(parser, None, "folder for model.onnx and policy.json (snapflow eval / bench load it)")


def run(args: argparse.Namespace) -> int:
    check_writable(args.output)
    from snapflow.sources import open_policy

    record = open_policy(args.policy).export_to(args.output, args.format)
    print(
        f"wrote {Path(args.output) / record['file']} (one graph: prefix and the one jump; inputs "
        f"{', '.join(record['inputs'])}; largest difference to PyTorch {record['max_abs_difference_to_pytorch']:.1e}) "
        f"and the policy's description; run it with: snapflow eval --policy {args.output} --modes snapflow-1"
    )
    return 0
