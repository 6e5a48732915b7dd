"""``snapflow serve``: LeRobot's own async-inference policy server, with snapflow's student types registered and
supported, for LeRobot's robot client to ask for ``policy_type=snapflow_<type>`` (lerobot >= 0.5)."""

from __future__ import annotations

import argparse
import ipaddress
from importlib.metadata import version
from pathlib import Path
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
    parser.add_argument(
        "--host",
        default="localhost",
        help="address to bind (LeRobot's default, the loopback); any other needs the three --tls-* files, or "
        "--insecure",
    )
    parser.add_argument("--port", type=COUNT, default=8080, help="port to listen on (LeRobot's default)")
    parser.add_argument(
        "--inference-latency",
        type=NON_NEGATIVE,
        help="LeRobot's floor on a chunk's round trip, in seconds: the server holds each chunk back until this much "
        "has passed (default: LeRobot's, 1/30 s; 0 shows what the one step saves)",
    )
    tls = parser.add_argument_group("TLS, for an address other than the loopback (mutual: clients are authenticated)")
    tls.add_argument("--tls-cert", metavar="FILE", help="the server's certificate (PEM)")
    tls.add_argument("--tls-key", metavar="FILE", help="the server's private key (PEM)")
    tls.add_argument(
        "--tls-client-ca", metavar="FILE", help="the CA certificate (PEM) that signed the clients' certificates"
    )
    parser.add_argument(
        "--insecure",
        action="store_true",
        help="bind an address other than the loopback without TLS (LeRobot's own robot client speaks no TLS): "
        "anyone who reaches the port can load policies and drive them",
    )


def _loopback(host: str) -> bool:
    try:
        return host == "localhost" or ipaddress.ip_address(host).is_loopback
    except ValueError:  # a host name other than localhost
        return False


def run(args: argparse.Namespace) -> int:
    tls = [args.tls_cert, args.tls_key, args.tls_client_ca]
    if any(tls) and not all(tls):
        raise InvalidInputError("TLS needs all three of --tls-cert, --tls-key and --tls-client-ca")
    if not _loopback(args.host) and not all(tls) and not args.insecure:
        raise InvalidInputError(
            f"--host {args.host} is reachable from other machines: give --tls-cert, --tls-key and --tls-client-ca "
            "(mutual TLS), or --insecure where the network is yours alone (or keep the loopback and tunnel to it, "
            "e.g. ssh -L)"
        )
    # a missing LeRobot is named with its install command by run_command
    if not lerobot_loads_plugins():
        raise InvalidInputError(
            f"snapflow serve needs lerobot >= {PLUGIN_LEROBOT} (Python >= 3.12), whose tools load third-party "
            f"policy types; lerobot {version('lerobot')} is installed"
        )
    from lerobot.async_inference.configs import PolicyServerConfig

    from snapflow.adapters.lerobot.serve import log_directory, serve, tls_credentials

    credentials = tls_credentials(*map(Path, tls)) if all(tls) else None
    latency = {} if args.inference_latency is None else {"inference_latency": args.inference_latency}
    serve(
        PolicyServerConfig(host=args.host, port=args.port, **latency),
        credentials,
        ready=lambda: print(
            f"serving SnapFlow students on {args.host}:{args.port}{' over mutual TLS' if credentials else ''}; the "
            f"robot client asks for policy_type=snapflow_<type>; LeRobot's server log: {log_directory() / 'logs'}",
            flush=True,
        ),
    )
    return 0
