"""What every ``snapflow`` command shares: the parser's one-line errors and defaults in the help, the checked
argument types, the flag groups several commands take (output folder, training flags from ``TrainConfig``, the
objective's flags, the fast path, threads and progress), the output-folder check, and the run of a command with its
errors and Ctrl-C told in one line.

Plain Python at import, as every command module is at the top (see :mod:`snapflow.cli`)."""

from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
import tomllib
from collections.abc import Callable
from pathlib import Path
from typing import Any, NoReturn

from snapflow import install_command
from snapflow.envs.factory import make_benchmark
from snapflow.errors import InvalidInputError, SnapflowError
from snapflow.inference.fast_paths import FAST_PATHS
from snapflow.objective.options import PAPER_TARGET_STEPS
from snapflow.objective.registry import methods, targets
from snapflow.training.config import TEACHER_TRAINING, TrainConfig
from snapflow.training.recipes import RECIPES, TargetOption, parse_target_steps

# TrainConfig fields every training command takes, with their help
TRAINING_OPTIONS = {
    "steps": "optimisation steps",
    "batch_size": "training pairs per step, over all the processes of an accelerate launch",
    "learning_rate": "peak learning rate (linear warm-up, then cosine decay)",
    "warmup_steps": "steps of linear warm-up to the peak learning rate",
    "seed": "seed of the initialisation, the batches and the noise",
    "checkpoint_every": "steps between checkpoints (an interrupted run resumes from the last one)",
}
# the pip extra that installs each optional module a command may need
EXTRAS = {
    "lerobot": "lerobot",
    "metaworld": "metaworld",
    "mujoco": "metaworld",
    "onnx": "onnx",
    "onnxruntime": "onnx",
    "onnxscript": "onnx",
    "ray": "ray",
}
TASKS_HELP = (
    "comma-separated sets of the benchmark's tasks (metaworld: mt10, the default, or mt50; libero: libero_spatial, "
    "the default, libero_object, libero_goal, libero_10) and task names (libero: <suite>_<index>)"
)
# the deprecated ``--compile MODE``: the fast path each torch.compile mode is registered as
COMPILE_FAST_PATHS = {
    "default": "compile",
    "reduce-overhead": "compile-reduce-overhead",
    "max-autotune": "compile-max-autotune",
}
RECIPE_SUMMARIES = "; ".join(f"{name}: {recipe.summary}" for name, recipe in RECIPES.items())
INTERRUPTED = 130  # what main returns after Ctrl-C: 128 + SIGINT, the status a shell shows for it
BUG = 1  # what main returns after an error that is snapflow's, not the user's (Python's own status for it)


class Parser(argparse.ArgumentParser):
    """argparse with a one-line error (the problem, then where to read more) instead of a usage dump."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


class HelpFormatter(argparse.HelpFormatter):
    """Each option's help ends with its default, where it has one."""

    def _get_help_string(self, action: argparse.Action) -> str:
        text, default = action.help or "", action.default
        if not action.option_strings or default is None or default is False or default == argparse.SUPPRESS:
            return text
        if "default:" in text:  # the help states a default the parser cannot hold
            return text
        if isinstance(default, list):  # as typed: space-separated values, or one comma-separated list
            default = (" " if action.nargs in ("+", "*") else ",").join(map(str, default))
        return f"{text} (default: {str(default).replace('%', '%%')})"


def number(kind: type, minimum: float | None = None, maximum: float | None = None, strict: bool = False) -> Callable:
    """An argparse type: a finite ``kind`` within [minimum, maximum] (``strict``: the open interval)."""

    def parse(text: str) -> Any:
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(
                f"{'an integer' if kind is int else 'a number'} is needed, got {text!r}"
            ) from None
        if not math.isfinite(value):
            raise argparse.ArgumentTypeError(f"a finite number is needed, got {text!r}")
        if minimum is not None and (value <= minimum if strict else value < minimum):
            raise argparse.ArgumentTypeError(f"must be {'above' if strict else 'at least'} {minimum}, got {text}")
        if maximum is not None and (value >= maximum if strict else value > maximum):
            raise argparse.ArgumentTypeError(f"must be {'below' if strict else 'at most'} {maximum}, got {text}")
        return value

    return parse


COUNT = number(int, 1)  # episodes, steps, repeats, workers, sizes: 0 and negatives are refused, never defaulted
NON_NEGATIVE_COUNT = number(int, 0)
SHARE = number(float, 0, 1)
POSITIVE = number(float, 0, strict=True)
NON_NEGATIVE = number(float, 0)


def argument_type(parse: Callable[[str], Any]) -> Callable[[str], Any]:
    """An argparse type from a parser of the API: its ValueError becomes argparse's one-line refusal."""

    def convert(text: str) -> Any:
        try:
            return parse(text)
        except ValueError as error:
            raise argparse.ArgumentTypeError(str(error)) from None

    return convert


_target_steps = argument_type(parse_target_steps)
_target_option = argument_type(TargetOption.parse)


def tasks(benchmark_name: str, value: str | None) -> list[str]:
    """``--tasks`` of the benchmark (None: its default tasks); a mistyped task or set is refused by name."""
    benchmark = make_benchmark(benchmark_name)
    return list(benchmark.default_tasks) if value is None else benchmark.resolve_tasks(value)


def check_writable(output: str | Path) -> None:
    """Refuse, before any work, an output folder that cannot be created or written (a probe file in the nearest
    existing folder: permission bits alone miss read-only file systems and root)."""
    path = Path(output).absolute()
    existing = next(folder for folder in (path, *path.parents) if folder.exists())
    if not existing.is_dir():
        raise InvalidInputError(
            f"cannot write to {output}: {existing} is a file, not a folder; choose another --output"
        )
    try:
        with tempfile.TemporaryFile(dir=existing):
            pass
    except OSError as error:
        raise InvalidInputError(
            f"cannot write to {output}: {error.strerror.lower()} in {existing}; choose another --output"
        ) from None


def given(values: dict[str, Any]) -> dict[str, Any]:
    """The values of the flags given (None: not given, the library's default stands)."""
    return {name: value for name, value in values.items() if value is not None}


def print_trained(message: str) -> None:
    """A training command's last line, from the main process of an ``accelerate launch`` only (or the only one)."""
    from accelerate import PartialState  # after training: the parser loads no torch

    if PartialState().is_main_process:
        print(message)


def training_overrides(args: argparse.Namespace) -> dict[str, Any]:
    """The TrainConfig fields the training flags set (None: not given)."""
    return {name: getattr(args, name) for name in (*TRAINING_OPTIONS, "ema_decay")}


def add_command(
    subparsers: Any,
    name: str,
    help: str,
    run: Callable[[argparse.Namespace], int],
    interrupted: Callable[[argparse.Namespace], str],
) -> argparse.ArgumentParser:
    """The sub-command ``name``, with the flags every command takes (``--no-progress``, ``--threads``); ``run``
    runs it, ``interrupted`` says what Ctrl-C left."""
    parser = subparsers.add_parser(name, help=help, description=help, formatter_class=HelpFormatter)
    parser.set_defaults(run=run, interrupted=interrupted)
    parser.add_argument("--no-progress", action="store_true", help="hide progress bars")
    parser.add_argument(
        "--threads",
        type=COUNT,
        help="torch CPU threads (default: torch's, one per core; give 1 where other jobs share the cores: "
        "multi-threaded ops then wait on each other's time slices, ten times slower or worse)",
    )
    return parser


def add_output(parser: argparse.ArgumentParser, default: str | None, help: str) -> None:
    """``--output`` (``--output-dir`` kept as an alias), the one name for where every command writes."""
    parser.add_argument("--output", "--output-dir", dest="output", required=default is None, default=default, help=help)


def add_training_options(parser: argparse.ArgumentParser, base: TrainConfig | None, data_required: bool = True) -> None:
    """``--data``, ``--output``, the TrainConfig fields of ``TRAINING_OPTIONS`` (defaults from ``base``; None: the
    command picks its base once it knows the policy), ``--resume`` and ``--keep-progress``."""
    parser.add_argument("--data", required=data_required, help="demonstrations directory written by `snapflow collect`")
    add_output(parser, None, "run directory for checkpoints")
    for name, help in TRAINING_OPTIONS.items():
        kind = type(getattr(TEACHER_TRAINING, name))
        parser.add_argument(
            f"--{name.replace('_', '-')}",
            type=POSITIVE if kind is float else (NON_NEGATIVE_COUNT if name in ("seed", "warmup_steps") else COUNT),
            default=getattr(base, name) if base is not None else None,
            help=help if base is not None else f"{help} (default: the recipe's; for LeRobot the paper's training)",
        )
    parser.add_argument(
        "--ema-decay",
        type=number(float, 0, 1, strict=True),
        default=base.ema_decay if base is not None else None,
        help="save an exponential moving average of the trained weights with this decay (e.g. 0.999) as each "
        "checkpoint's policy; the raw weights are kept beside it for --resume (default: off)",
    )
    parser.add_argument("--resume", action="store_true", help="continue from the run's latest checkpoint")
    parser.add_argument(
        "--keep-progress",
        metavar="DIR",
        help="also keep a copy of the latest checkpoint (all that --resume reads) in DIR, a folder to commit or carry "
        "to another machine; with --resume, an --output without a checkpoint continues from the one kept there",
    )


def _name_value(what: str, example: str) -> Callable[[str], tuple[str, Any]]:
    """The argument type of a repeatable ``NAME=VALUE`` flag (``--objective-option``, ``--policy-option``): the value
    read as in TOML (0.9, 10, true, ["image2"]), or else as text (conv)."""

    def parse(text: str) -> tuple[str, Any]:
        name, equals, value = text.partition("=")
        if not equals or not name.isidentifier():
            raise argparse.ArgumentTypeError(f"{what} reads NAME=VALUE, e.g. {example}; got {text!r}")
        try:
            return name, tomllib.loads(f"value = {value}")["value"]
        except tomllib.TOMLDecodeError:
            return name, value

    return parse


def add_name_value_option(parser: argparse.ArgumentParser, flag: str, what: str, example: str, help: str) -> None:
    """A repeatable ``NAME=VALUE`` flag (``--objective-option``, ``--policy-option``), each value read as in TOML."""
    parser.add_argument(flag, type=_name_value(what, example), action="append", metavar="NAME=VALUE", help=help)


def add_consistency_weight(parser: argparse.ArgumentParser, default: float | None, recipe: str = "") -> None:
    """``--consistency-weight`` (``--lambda``): the one declaration of lambda; ``recipe`` ends its help."""
    parser.add_argument(
        "--consistency-weight",
        "--lambda",
        type=NON_NEGATIVE,
        default=default,
        dest="consistency_weight",
        help="lambda, the weight of the one-step (consistency) loss" + recipe,
    )


def add_objective_options(parser: argparse.ArgumentParser) -> None:
    """``--method``, ``--lambda``, ``--target`` and ``--target-steps``, each None unless given (the recipe's stands)."""
    recipe = " (default: the recipe's)"
    parser.add_argument(
        "--method", choices=methods(), help="distillation objective (the others are baselines)" + recipe
    )
    add_consistency_weight(parser, None, recipe)
    parser.add_argument(
        "--target",
        choices=targets(),
        help="SnapFlow's one-step target: the average of Euler velocities, bootstrapped from the model's own half-jumps, "
        "or Euler's with an energy term over several one-step samples per observation (keeps modes)" + recipe,
    )
    parser.add_argument(
        "--target-steps",
        type=_target_steps,
        help=f"Euler steps the target spans ({PAPER_TARGET_STEPS}: the paper); a schedule such as 2,4,8 splits training "
        "into equal stages" + recipe,
    )


def add_target_options(parser: argparse.ArgumentParser, default: tuple[str, ...]) -> None:
    """``--targets``: the SnapFlow targets a command compares, the first the reference."""
    parser.add_argument(
        "--targets",
        nargs="+",
        type=_target_option,
        default=[TargetOption.parse(text) for text in default],
        help="TARGET:STEPS options, the first the reference: euler:8, euler:2,4,8 (a schedule), bootstrap:8",
    )


class _DeprecatedCompileFlag(argparse.Action):
    """``--compile MODE``, the torch.compile flag from before the fast paths had names: still read, as ``--fast-path``
    of that mode's name, with one line on stderr."""

    def __call__(
        self, parser: argparse.ArgumentParser, namespace: argparse.Namespace, values: Any, option_string: Any = None
    ) -> None:
        name = COMPILE_FAST_PATHS[values]
        print(f"{parser.prog}: warning: --compile is deprecated; use --fast-path {name}", file=sys.stderr)
        setattr(namespace, self.dest, name)


def add_fast_path(parser: argparse.ArgumentParser, runs: str) -> None:
    """``--fast-path NAME``, a registered fast path (:mod:`snapflow.inference.fast_paths`) that ``runs`` what the
    command times or evaluates, and ``--compile MODE``, its deprecated alias."""
    flags = parser.add_mutually_exclusive_group()
    described = "; ".join(f"{name}: {entry.description}" for name, entry in FAST_PATHS.items())
    flags.add_argument("--fast-path", choices=list(FAST_PATHS), help=f"the deployment fast path {runs} ({described})")
    flags.add_argument(
        "--compile",
        dest="fast_path",
        choices=list(COMPILE_FAST_PATHS),
        action=_DeprecatedCompileFlag,
        help=argparse.SUPPRESS,
    )


def training_interrupted(args: argparse.Namespace) -> str:
    """What Ctrl-C left of a training run: its last checkpoint, or nothing yet."""
    from snapflow.policies.checkpoint import LATEST  # imported at the interrupt: the parser loads no torch

    latest = Path(args.output) / LATEST
    if latest.is_file():
        checkpoint = json.loads(latest.read_text()).get("checkpoint", "?")
        return f"interrupted; {args.output} keeps its last checkpoint ({checkpoint}): run the same command with --resume to continue"
    return (
        f"interrupted before the first checkpoint (one every --checkpoint-every steps); nothing was kept in "
        f"{args.output}: run the command again"
    )


def nothing_written(args: argparse.Namespace) -> str:
    """What Ctrl-C left of a command that writes only at its end."""
    return f"interrupted; nothing was written to {args.output}"


def runs_kept(args: argparse.Namespace) -> str:
    """What Ctrl-C left of a command of cached runs."""
    return "interrupted; finished runs are kept: run the same command again to continue"


def run_command(args: argparse.Namespace) -> int:
    """Run the parsed command: its exit code; 2 after an error the user can fix (a :class:`SnapflowError`, a file
    or folder the system refused, a missing extra with its install command), told in one line on stderr;
    :data:`INTERRUPTED` after Ctrl-C, with what was kept; :data:`BUG` after anything else, a bug in snapflow, shown
    with its traceback and where to report it."""
    prefix = f"snapflow {args.command}:"
    if args.threads:
        import torch

        torch.set_num_threads(args.threads)
    try:
        return args.run(args)
    except SnapflowError as error:
        print(f"{prefix} error: {error}", file=sys.stderr)
    except ModuleNotFoundError as error:
        module = (error.name or "").partition(".")[0]
        if module not in EXTRAS:
            return _report_bug(prefix)
        print(
            f"{prefix} error: this needs {module}, which is not installed: {install_command(EXTRAS[module])}",
            file=sys.stderr,
        )
    except OSError as error:  # a path the system refused: missing, taken, read-only, a full disk, ...
        where = f": {error.filename}" if error.filename else ""  # our own messages name their paths themselves
        print(f"{prefix} error: {error.strerror or error}{where}", file=sys.stderr)
    except KeyboardInterrupt:
        print(f"{prefix} {args.interrupted(args)}", file=sys.stderr)
        return INTERRUPTED
    except Exception:
        return _report_bug(prefix)
    return 2


def _report_bug(prefix: str) -> int:
    """The traceback of the exception being handled, then a line saying it is snapflow's bug and where to report
    it; returns :data:`BUG`."""
    import traceback

    from snapflow import DISTRIBUTION, __version__

    traceback.print_exc()
    print(
        f"{prefix} this is a bug in snapflow {__version__}, not a mistake in your input: please report it, with the "
        f"command you ran and the traceback above, {_where_to_report(DISTRIBUTION)}",
        file=sys.stderr,
    )
    return BUG


def _where_to_report(distribution: str) -> str:
    """The project's issue tracker as its installed metadata names it, else its home page."""
    from importlib.metadata import metadata

    urls = dict(entry.split(", ", 1) for entry in metadata(distribution).get_all("Project-URL") or [])
    url = urls.get("Issues") or urls.get("Homepage")
    return f"at {url}" if url else f"to the maintainers of {distribution}"
