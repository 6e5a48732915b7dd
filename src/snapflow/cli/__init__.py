"""The ``snapflow`` command line: one sub-command per job, each a thin shell over the Python API, in a module of its
own that declares its flags (``add_parser``) beside its run (``run``); what they share is in :mod:`.common`.

Defaults and choices are read from the settings dataclasses and the registries, never restated here. Parsing loads
no torch (those settings modules are plain Python, and a command imports what it needs inside ``run``): counts,
fractions, sampling modes, task names and the output folder are checked before a command imports what it needs, so
``--help`` and a mistyped argument answer at once. Every error the user can fix is one line,
``snapflow <command>: error: ...``, and exit code 2.
"""

from __future__ import annotations

import argparse
import os
import signal
import sys
from typing import NoReturn

from snapflow import __version__
from snapflow.cli import (
    bench,
    bench_targets,
    checkpoints,
    collect,
    demo,
    diagnose,
    distill,
    eval,
    experts,
    export,
    serve,
    sweep,
    toy,
    toy_compare,
    train,
)
from snapflow.cli.common import INTERRUPTED, HelpFormatter, Parser, run_command

# the sub-commands, in the order `snapflow --help` lists them
COMMANDS = (
    toy,
    toy_compare,
    collect,
    experts,
    train,
    distill,
    eval,
    diagnose,
    bench,
    export,
    serve,
    bench_targets,
    sweep,
    checkpoints,
    demo,
)


def build_parser() -> argparse.ArgumentParser:
    """The ``snapflow`` parser, every sub-command's flags in it; building it imports no torch."""
    parser = Parser(
        prog="snapflow",
        description="One-step action generation for flow-matching policies.",
        formatter_class=HelpFormatter,
    )
    parser.add_argument("--version", action="version", version=f"snapflow {__version__}")
    subparsers = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for command in COMMANDS:
        command.add_parser(subparsers)
    return parser


def command_parsers(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    """Each sub-command's parser in ``parser`` (:func:`build_parser`'s), by name, in the order ``--help`` lists them."""
    return next(action for action in parser._actions if isinstance(action, argparse._SubParsersAction)).choices


def main(argv: list[str] | None = None) -> int:
    """``snapflow ARGV`` (default: the process's arguments): the exit code (see :func:`.common.run_command`)."""
    return run_command(build_parser().parse_args(argv))


def entry_point() -> NoReturn:
    """The ``snapflow`` command: :func:`main`, whose code becomes the exit status, except after Ctrl-C: then,
    once the message is out, the process ends by SIGINT itself, as Unix asks of a program that cleans up after one
    (a calling shell loop stops too; the shell shows 130). Python 3.11 does the same of its own accord when the
    interrupt landed inside an ``exec`` of a string (dataclasses, mpmath), so one way out is also the only way."""
    code = main()
    if code == INTERRUPTED:
        sys.stdout.flush()
        sys.stderr.flush()
        signal.signal(signal.SIGINT, signal.SIG_DFL)
        os.kill(os.getpid(), signal.SIGINT)
    sys.exit(code)


__all__ = ["build_parser", "command_parsers", "entry_point", "main"]
