"""``snapflow serve``: LeRobot's own async-inference policy server, with snapflow's student types registered and
supported, for LeRobot's robot client to ask for ``policy_type=snapflow_<type>`` (lerobot >= 0.5)."""

from __future__ import annotations

import argparse
from importlib.metadata import version
from typing import Any

from snapflow.adapters.lerobot_types import PLUGIN_LEROBOT, lerobot_loads_plugins
from snapflow.cli.common import COUNT, NON_NEGATIVE, add_command
from snapflow.errors import InvalidInputError


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
    parser.add_argument(
        "--inference-latency",
        type=NON_NEGATIVE,
        help="LeRobot's floor on a chunk's round trip, in seconds: the server holds each chunk back until this much "
        "has passed (default: LeRobot's, 1/30 s; 0 shows what the one step saves)",
    )


def run(args: argparse.Namespace) -> int:
    # a missing LeRobot is named with its install command by run_command
    if not lerobot_loads_plugins():
        raise InvalidInputError(
            f"snapflow serve needs lerobot >= {PLUGIN_LEROBOT} (Python >= 3.12), whose tools load third-party "
            f"policy types; lerobot {version('lerobot')} is installed"
        )
    from lerobot.async_inference.configs import PolicyServerConfig

    from snapflow.adapters.lerobot.serve import serve

    print(
        f"serving SnapFlow students on {args.host}:{args.port}; the robot client asks for policy_type=snapflow_<type>"
    )
    latency = {} if args.inference_latency is None else {"inference_latency": args.inference_latency}
    serve(PolicyServerConfig(host=args.host, port=args.port, **latency))
    return 0
