"""``snapflow serve``: LeRobot's own async-inference policy server, with snapflow's student types registered and
supported, for LeRobot's robot client to ask for ``policy_type=snapflow_<type>`` (lerobot >= 0.5)."""

from __future__ import annotations

import argparse
from importlib.metadata import version
from typing import Any

from snapflow.cli.common import COUNT, add_command

MINIMUM_LEROBOT = "0.5"  # the first release whose tools load third-party policy types


def add_parser(subparsers: Any) -> None:
    parser = add_command(
        subparsers,
        "serve",
        "serve distilled LeRobot students to LeRobot's robot client (LeRobot's async-inference policy server)",
        run,
        lambda _: "stopped serving",
    )
    parser.add_argument("--host", default="localhost", help="address to bind (LeRobot's default)")
    parser.add_argument("--port", type=COUNT, default=8080, help="port to listen on (LeRobot's default)")


def run(args: argparse.Namespace) -> int:
    from packaging.version import Version

    installed = version("lerobot")  # a missing LeRobot is named with its install command by run_command
    if Version(installed) < Version(MINIMUM_LEROBOT):
        raise ValueError(
            f"snapflow serve needs lerobot >= {MINIMUM_LEROBOT} (Python >= 3.12), whose tools load third-party "
            f"policy types; lerobot {installed} is installed"
        )
    from lerobot.async_inference.configs import PolicyServerConfig

    from snapflow.adapters.lerobot.serve import serve

    print(
        f"serving SnapFlow students on {args.host}:{args.port}; the robot client asks for policy_type=snapflow_<type>"
    )
    serve(PolicyServerConfig(host=args.host, port=args.port))
    return 0
