"""The ``snapflow`` command line: one sub-command per job, each a thin shell over the Python API.

Defaults and choices are read from the settings dataclasses and the registries, never restated here. Parsing loads
no torch (those settings modules are plain Python): counts, fractions, sampling modes, task names and the output
folder are checked before a command imports what it needs, so ``--help`` and a mistyped argument answer at once.
Every error the user can fix is one line, ``snapflow <command>: error: ...``, and exit code 2.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import signal
import sys
import tempfile
import time
import tomllib
from collections.abc import Callable
from dataclasses import MISSING, fields, replace
from importlib.metadata import version
from pathlib import Path
from typing import Any, NoReturn

from snapflow.adapters.lerobot_config import LEROBOT_TEACHERS, SMOLVLM_SIZES
from snapflow.benchmark.architectures import architectures
from snapflow.data.collect import EPISODES_PER_TASK
from snapflow.envs.base import SPLITS
from snapflow.envs.factory import BENCHMARKS, DEFAULT_BENCHMARK, make_benchmark
from snapflow.evaluation.config import N_ACT
from snapflow.flow.modes import SamplingMode
from snapflow.inference.compile import COMPILE_MODES
from snapflow.inference.formats import EXPORT_FORMATS
from snapflow.jobs.toy_config import ToyConfig
from snapflow.objective.options import TEACHER_VELOCITIES
from snapflow.objective.registry import OBJECTIVES, methods, targets
from snapflow.policies.factory import POLICIES
from snapflow.reporting.files import write_json, write_text
from snapflow.training.config import TEACHER_TRAINING, VAL_FRACTION, TrainConfig
from snapflow.training.recipes import (
    DEFAULT_RECIPE,
    LEROBOT_RECIPE,
    RECIPES,
    DistillSettings,
    TargetOption,
    parse_target_steps,
    student_settings,
)

# TrainConfig fields every training command takes, with their help
TRAINING_OPTIONS = {
    "steps": "optimisation steps",
    "batch_size": "training pairs per step",
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
}
TASKS_HELP = (
    "comma-separated sets of the benchmark's tasks (metaworld: mt10, the default, or mt50; libero: libero_spatial, "
    "the default, libero_object, libero_goal, libero_10) and task names (libero: <suite>_<index>)"
)
INTERRUPTED = 130  # what main returns after Ctrl-C: 128 + SIGINT, the status a shell shows for it


class _Parser(argparse.ArgumentParser):
    """argparse with a one-line error (the problem, then where to read more) instead of a usage dump."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


class _HelpFormatter(argparse.HelpFormatter):
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


def _number(kind: type, minimum: float | None = None, maximum: float | None = None, strict: bool = False) -> Callable:
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


COUNT = _number(int, 1)  # episodes, steps, repeats, workers, sizes: 0 and negatives are refused, never defaulted
NON_NEGATIVE_COUNT = _number(int, 0)
SHARE = _number(float, 0, 1)
POSITIVE = _number(float, 0, strict=True)
NON_NEGATIVE = _number(float, 0)


def _counts(text: str) -> tuple[int, ...]:
    """A comma-separated list of counts, e.g. batch sizes ``1,8,32``."""
    return tuple(COUNT(part) for part in text.split(","))


def _validation_share(text: str) -> float:
    value = SHARE(text)
    if value == 1:
        raise argparse.ArgumentTypeError("must be below 1 (some episodes must remain to train on), got 1")
    return value


def _argument_type(parse: Callable[[str], Any]) -> Callable[[str], Any]:
    """An argparse type from a parser of the API: its ValueError becomes argparse's one-line refusal."""

    def convert(text: str) -> Any:
        try:
            return parse(text)
        except ValueError as error:
            raise argparse.ArgumentTypeError(str(error)) from None

    return convert


_modes = _argument_type(lambda text: [SamplingMode.parse(name) for name in text.split(",")])
_target_steps = _argument_type(parse_target_steps)
_target_option = _argument_type(TargetOption.parse)


def _objective_option(text: str) -> tuple[str, Any]:
    """``NAME=VALUE``, the value read as in TOML (0.9, 10, true, [2, 4]), or else as text."""
    name, equals, value = text.partition("=")
    if not equals or not name.isidentifier():
        raise argparse.ArgumentTypeError(f"an objective option reads NAME=VALUE, e.g. adaptive_power=0.5; got {text!r}")
    try:
        return name, tomllib.loads(f"value = {value}")["value"]
    except tomllib.TOMLDecodeError:
        return name, value


def _default(cls: type, name: str) -> Any:
    field = next(field for field in fields(cls) if field.name == name)
    return field.default if field.default is not MISSING else field.default_factory()


def _tasks(benchmark_name: str, value: str | None) -> list[str]:
    benchmark = make_benchmark(benchmark_name)
    return list(benchmark.default_tasks) if value is None else benchmark.resolve_tasks(value)


def _check_writable(output: str | Path) -> None:
    """Refuse, before any work, an output folder that cannot be created or written (a probe file in the nearest
    existing folder: permission bits alone miss read-only file systems and root)."""
    path = Path(output).absolute()
    existing = next(folder for folder in (path, *path.parents) if folder.exists())
    if not existing.is_dir():
        raise ValueError(f"cannot write to {output}: {existing} is a file, not a folder; choose another --output")
    try:
        with tempfile.TemporaryFile(dir=existing):
            pass
    except OSError as error:
        raise ValueError(
            f"cannot write to {output}: {error.strerror.lower()} in {existing}; choose another --output"
        ) from None


def _given(values: dict[str, Any]) -> dict[str, Any]:
    """The values of the flags given (None: not given, the library's default stands)."""
    return {name: value for name, value in values.items() if value is not None}


def _training_overrides(args: argparse.Namespace) -> dict[str, Any]:
    """The TrainConfig fields the training flags set."""
    return {name: getattr(args, name) for name in (*TRAINING_OPTIONS, "ema_decay")}


def _train_config(args: argparse.Namespace, base: TrainConfig) -> TrainConfig:
    return replace(base, **_given(_training_overrides(args)))


def _toy(args: argparse.Namespace) -> int:
    _check_writable(args.output)
    from snapflow.jobs.toy import markdown_toy, plot_toy_result, run_toy_experiment

    config = ToyConfig(
        seed=args.seed,
        teacher_steps=args.teacher_steps,
        distill_steps=args.distill_steps,
        method=args.method,
        consistency_weight=args.consistency_weight,
        target=args.target,
        target_steps=args.target_steps,
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


def _toy_compare(args: argparse.Namespace) -> int:
    _check_writable(args.output)
    from snapflow.jobs.toy_compare import compare_targets, markdown_comparison

    base = ToyConfig(
        teacher_steps=args.teacher_steps, distill_steps=args.distill_steps, consistency_weight=args.consistency_weight
    )
    started = time.perf_counter()
    summary = compare_targets(args.targets, args.seeds, base, args.output, args.workers, not args.no_progress)
    print(markdown_comparison(summary))
    print(
        f"\ndone in {(time.perf_counter() - started) / 60:.1f} min; wrote comparison.json, comparison.md and comparison.png to {args.output}"
    )
    return 0


def _collect(args: argparse.Namespace) -> int:
    tasks = _tasks(args.env, args.tasks)
    _check_writable(args.output)
    benchmark = make_benchmark(args.env)
    if args.lerobot_dataset:  # LeRobot's import and the root are checked before any episode runs
        from snapflow.adapters.lerobot.dataset import check_dataset_root, write_lerobot_dataset

        check_dataset_root(args.lerobot_dataset)
    from snapflow.data.collect import collect

    progress = not args.no_progress
    demonstrations = collect(benchmark, tasks, args.episodes, args.output, args.image_size, progress)
    if args.lerobot_dataset:
        write_lerobot_dataset(
            demonstrations, args.lerobot_dataset, args.repo_id, benchmark.fps, benchmark.camera, progress
        )
    also = f" and as a LeRobotDataset to {args.lerobot_dataset}" if args.lerobot_dataset else ""
    print(
        f"wrote {len(demonstrations.episodes)} successful expert episodes ({len(demonstrations.states)} steps) "
        f"to {args.output}{also}"
    )
    return 0


def _experts(args: argparse.Namespace) -> int:
    tasks = _tasks(args.env, args.tasks)
    _check_writable(args.output)
    from snapflow.evaluation.experts import EXPERTS_MD, run_experts

    report = run_experts(
        make_benchmark(args.env), tasks, args.output, args.split, args.episodes, not args.no_progress, args.workers
    )
    mean = report["tasks"]["mean"]
    print(
        f"scripted experts: {100 * mean['success_rate']:.1f}% mean success over {len(tasks)} task(s) "
        f"({mean['successes']} / {mean['episodes']} episodes); per task in {Path(args.output) / EXPERTS_MD}"
    )
    return 0


def _train(args: argparse.Namespace) -> int:
    if (args.policy in LEROBOT_TEACHERS) != bool(args.dataset) or bool(args.data) == bool(args.dataset):
        raise ValueError(
            f"give --data with a built-in policy ({', '.join(POLICIES)}) or --dataset with --policy "
            f"{' / '.join(LEROBOT_TEACHERS)} (a LeRobotDataset)"
        )
    _check_writable(args.output)
    config = _train_config(args, TEACHER_TRAINING)
    if args.dataset:
        return _train_lerobot(args, config)
    from snapflow.data.demonstrations import Demonstrations
    from snapflow.training.stages import policy_config_for, train_teacher

    overrides = _given(
        {"chunk_length": args.chunk_length, "image_size": args.image_size, "use_image": args.use_image or None}
    )
    policy = policy_config_for(args.policy, Demonstrations.load(args.data), args.state_dim, **overrides)
    state = train_teacher(args.data, args.output, policy, config, args.val_fraction, args.resume, not args.no_progress)
    print(f"teacher trained to step {state['step']} in {state['wall_time_s']:.0f} s; checkpoints in {args.output}")
    return 0


def _train_lerobot(args: argparse.Namespace, config: TrainConfig) -> int:
    from snapflow.training.lerobot import EXPORT_DIRECTORY, train_smolvla_teacher

    size = SMOLVLM_SIZES[args.smolvlm]
    if args.image_size:
        size = replace(size, image_size=args.image_size)
    from snapflow.adapters.hub import dataset_source

    state = train_smolvla_teacher(
        *dataset_source(args.dataset, args.repo_id),
        args.output,
        config,
        size,
        chunk_size=args.chunk_length or 8,
        n_action_steps=args.n_action_steps,
        val_fraction=args.val_fraction,
        resume=args.resume,
        progress=not args.no_progress,
    )
    print(
        f"SmolVLA teacher trained to step {state['step']} in {state['wall_time_s']:.0f} s; "
        f"LeRobot policy in {Path(args.output) / EXPORT_DIRECTORY}"
    )
    return 0


def _distill(args: argparse.Namespace) -> int:
    built_in = bool(args.teacher and args.data) and not (args.policy or args.dataset)
    lerobot = bool(args.policy and args.dataset) and not (args.teacher or args.data)
    if not (built_in or lerobot):
        raise ValueError("give either --teacher and --data (a built-in policy) or --policy and --dataset (LeRobot)")
    _check_writable(args.output)
    overrides = {
        "alpha": args.alpha,
        "consistency_weight": args.consistency_weight,
        "teacher_velocity_clamp": args.clamp,
        "freeze_prefix": False if args.train_prefix else None,
        "method": args.method,
        "teacher_velocity": args.teacher_velocity,
        "target_time": False if args.no_target_time else None,
        "target": args.target,
        "target_steps": args.target_steps,
        "intermediate_jumps": args.intermediate_jumps,
        "objective_options": dict(args.objective_option) if args.objective_option else None,
    }
    if lerobot:  # before the settings, whose LeRobot training imports LeRobot's side
        from snapflow.adapters.hub import dataset_source

        dataset_root, repo_id = dataset_source(args.dataset, args.repo_id)
    train, settings = student_settings(args.recipe, lerobot, _given(_training_overrides(args)), _given(overrides))
    if lerobot:
        from snapflow.training.lerobot import EXPORT_DIRECTORY, distill_lerobot

        state = distill_lerobot(
            args.policy, dataset_root, repo_id, args.output, train, settings, args.resume, not args.no_progress
        )
        print(
            f"SnapFlow student trained to step {state['step']}; LeRobot policy in {Path(args.output) / EXPORT_DIRECTORY}"
        )
        return 0
    from snapflow.training.stages import distill

    state = distill(
        args.teacher,
        args.data,
        args.output,
        train,
        settings,
        resume=args.resume,
        progress=not args.no_progress,
    )
    print(
        f"SnapFlow student trained to step {state['step']} in {state['wall_time_s']:.0f} s; checkpoints in {args.output}"
    )
    return 0


def _eval(args: argparse.Namespace) -> int:
    if args.lerobot_env:
        return _eval_in_lerobot_env(args)
    # every registered benchmark is checked again below once the policies name theirs; a typo is caught here first
    _tasks(args.env or DEFAULT_BENCHMARK, args.tasks)
    _check_writable(args.output)
    from snapflow.evaluation.pipeline import evaluate, labelled_runs, trained_benchmark
    from snapflow.evaluation.report import markdown_report, write_report
    from snapflow.inference.compile import compile_policy
    from snapflow.sources import open_policy

    modes = dict(_policy_modes(entry, args.modes) for entry in args.policy)
    policies = {path: (open_policy(path), policy_modes) for path, policy_modes in modes.items()}
    if args.compile:
        for policy, _ in policies.values():
            compile_policy(policy.policy, args.compile)
    env = args.env or trained_benchmark(next(iter(policies.values()))[0])
    report = evaluate(
        labelled_runs(policies),
        make_benchmark(env),
        _tasks(env, args.tasks),
        args.episodes,
        data=args.data,
        progress=not args.no_progress,
        **_given({"n_act": args.n_act, "seed": args.seed}),
    )
    write_report(report, args.output)
    print(markdown_report(report))
    print(f"wrote report.json, report.md and PNG plots to {args.output}")
    return 0


def _policy_modes(entry: str, default: list[SamplingMode]) -> tuple[str, list[SamplingMode]]:
    """``PATH`` (the --modes) or ``PATH=MODES``: the sampling modes of one policy of several."""
    path, separator, modes = entry.rpartition("=")
    if not separator:
        return entry, default
    return path, [SamplingMode.parse(name) for name in modes.split(",")]


def _diagnose(args: argparse.Namespace) -> int:
    _check_writable(args.output)
    from snapflow.evaluation.diagnosis import diagnose_student, markdown_diagnosis, write_diagnosis
    from snapflow.sources import open_policy

    diagnosis = diagnose_student(
        open_policy(args.teacher),
        open_policy(args.student),
        args.task,
        args.episodes,
        args.n_act,
        args.teacher_steps,
        args.env,
        args.data,
        seed=args.seed,
        progress=not args.no_progress,
    )
    write_diagnosis(diagnosis, args.output)
    print(markdown_diagnosis(diagnosis))
    print(f"wrote diagnosis.json, diagnosis.md, phases.png and the chunk plots to {args.output}")
    return 0


def _eval_in_lerobot_env(args: argparse.Namespace) -> int:
    if len(args.policy) != 1:
        raise ValueError("--lerobot-env evaluates one distilled LeRobot policy directory at a time")
    _check_writable(args.output)
    from snapflow.evaluation.lerobot_env import evaluate_in_lerobot_env, lerobot_eval_table, write_lerobot_eval

    report = evaluate_in_lerobot_env(
        args.policy[0],
        args.lerobot_env,
        args.modes,
        args.episodes,
        args.env_task,
        args.n_act,
        args.n_envs,
        max_episode_steps=args.max_episode_steps,
        compile_mode=args.compile,
        **_given({"seed": args.seed}),
    )
    write_lerobot_eval(report, args.output)
    print(lerobot_eval_table(report))
    print(f"wrote report.json, report.md and each mode's eval_info.json to {args.output}")
    return 0


def _bench(args: argparse.Namespace) -> int:
    _check_writable(args.output)
    import torch

    from snapflow.benchmark.bench import markdown_bench, run_bench, vision_in_bfloat16, write_bench
    from snapflow.benchmark.subjects import make_subject

    device = torch.device(args.device or ("cuda" if torch.cuda.is_available() else "cpu"))
    dtype = {"float32": torch.float32, "bfloat16": torch.bfloat16, "float16": torch.float16}[args.dtype]
    subject = make_subject(args.policy, args.architecture, device, dtype, args.vlm)
    vision_difference = vision_in_bfloat16(subject) if args.vision_dtype else None
    distill_step = None
    if args.distill_batch_sizes:  # first, in place: before anything is compiled
        from snapflow.benchmark.training_cost import distillation_step_cost

        distill_step = distillation_step_cost(
            subject.policy, subject.observation, subject.noise, args.distill_batch_sizes, subject.time_sampler
        )
    report = run_bench(
        subject,
        args.warmup,
        args.repeats,
        args.compile,
        profile=not args.no_profile,
        batch_sizes=args.batch_sizes,
        tf32=args.tf32,
    )
    if distill_step is not None:
        report["distill_step"] = distill_step
    if vision_difference is not None:
        report["vision_bfloat16"] = {"max_abs_action_difference": vision_difference}
    write_bench(report, args.output)
    print(markdown_bench(report))
    print(f"wrote bench.json, bench.md, latency.png{'' if args.no_profile else ' and profile.txt'} to {args.output}")
    return 0


def _export(args: argparse.Namespace) -> int:
    _check_writable(args.output)
    from snapflow.sources import open_policy

    record = open_policy(args.policy).export_to(args.output, args.format)
    print(
        f"wrote {Path(args.output) / record['file']} (one graph: prefix and the one jump; inputs "
        f"{', '.join(record['inputs'])}; largest difference to PyTorch {record['max_abs_difference_to_pytorch']:.1e}) "
        f"and the policy's description; run it with: snapflow eval --policy {args.output} --modes snapflow-1"
    )
    return 0


def _bench_targets(args: argparse.Namespace) -> int:
    _check_writable(args.output)

    from snapflow.benchmark.training_cost import checkpoint_training_cost, markdown_training_cost

    result = checkpoint_training_cost(args.teacher, args.data, args.targets, args.batch_size, args.warmup, args.repeats)
    table = markdown_training_cost(result)
    output = Path(args.output)
    write_json(output / "training_cost.json", {**result, "teacher": str(args.teacher), "data": str(args.data)})
    write_text(output / "training_cost.md", table + "\n")
    print(table)
    print(f"wrote training_cost.json and training_cost.md to {output}")
    return 0


def _sweep(args: argparse.Namespace) -> int:
    from snapflow.jobs.sweep import load_sweep, run_sweeps, write_results

    configs = [load_sweep(path) for path in args.configs]
    for config in configs:
        config.table_names(args.tables)  # a mistyped table is refused before anything runs
    if not args.report_only:
        run_sweeps([config.only(args.tables) for config in configs], args.workers, not args.no_progress)
    for config in configs:
        write_results(config, args.document, args.tables)
        print(f"{config.name}: wrote results.json, tables.md and PNG plots to {config.results_dir}")
    if args.document:
        print(f"updated the sweep tables in {args.document}")
    return 0


def _demo(args: argparse.Namespace) -> int:
    _check_writable(args.output)
    from snapflow.evaluation.report import markdown_report
    from snapflow.jobs.demo import PRESETS, run_demo, with_recipe

    preset = PRESETS["full" if args.full else "fast"]
    report = run_demo(with_recipe(preset, args.recipe), args.output, not args.no_progress, args.resume)
    print(markdown_report(report))
    print(f"wrote report.json, report.md and PNG plots to {args.output}")
    return 0


def _training_interrupted(args: argparse.Namespace) -> str:
    from snapflow.policies.checkpoint import LATEST  # imported at the interrupt: the parser loads no torch

    latest = Path(args.output) / LATEST
    if latest.is_file():
        checkpoint = json.loads(latest.read_text()).get("checkpoint", "?")
        return f"interrupted; {args.output} keeps its last checkpoint ({checkpoint}): run the same command with --resume to continue"
    return (
        f"interrupted before the first checkpoint (one every --checkpoint-every steps); nothing was kept in "
        f"{args.output}: run the command again"
    )


def _nothing_written(args: argparse.Namespace) -> str:
    return f"interrupted; nothing was written to {args.output}"


def _collect_interrupted(args: argparse.Namespace) -> str:
    from snapflow.data.demonstrations import META_FILE

    if args.lerobot_dataset and (Path(args.output) / META_FILE).is_file():
        return f"interrupted; the demonstrations are saved in {args.output}, no LeRobotDataset was written"
    return f"interrupted; no demonstrations were saved in {args.output}"


def _runs_kept(args: argparse.Namespace) -> str:
    return "interrupted; finished runs are kept: run the same command again to continue"


def _demo_interrupted(args: argparse.Namespace) -> str:
    return f"interrupted; finished stages and the last checkpoint are kept in {args.output}: continue with --resume"


def _command(
    commands: Any, name: str, help: str, run: Callable[[argparse.Namespace], int], interrupted: Callable, common: Any
) -> argparse.ArgumentParser:
    parser = commands.add_parser(name, parents=[common], help=help, description=help, formatter_class=_HelpFormatter)
    parser.set_defaults(run=run, interrupted=interrupted)
    return parser


def _add_output(parser: argparse.ArgumentParser, default: str | None, help: str) -> None:
    """``--output`` (``--output-dir`` kept as an alias), the one name for where every command writes."""
    parser.add_argument("--output", "--output-dir", dest="output", required=default is None, default=default, help=help)


def _add_training_options(
    parser: argparse.ArgumentParser, base: TrainConfig | None, data_required: bool = True
) -> None:
    """``--data``, ``--output``, the TrainConfig fields of ``TRAINING_OPTIONS`` (defaults from ``base``; None: the
    command picks its base once it knows the policy) and ``--resume``."""
    parser.add_argument("--data", required=data_required, help="demonstrations directory written by `snapflow collect`")
    _add_output(parser, None, "run directory for checkpoints")
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
        type=_number(float, 0, 1, strict=True),
        default=base.ema_decay if base is not None else None,
        help="save an exponential moving average of the trained weights with this decay (e.g. 0.999) as each "
        "checkpoint's policy; the raw weights are kept beside it for --resume (default: off)",
    )
    parser.add_argument("--resume", action="store_true", help="continue from the run's latest checkpoint")


def _add_objective_options(parser: argparse.ArgumentParser, cls: type | None) -> None:
    """``--method``, ``--lambda``, ``--target`` and ``--target-steps`` with the defaults of the dataclass ``cls``
    (ToyConfig), or none (None: the distill recipe's)."""
    recipe = "" if cls else " (default: the recipe's)"
    parser.add_argument(
        "--method",
        choices=methods(),
        default=_default(cls, "method") if cls else None,
        help="distillation objective (the others are baselines)" + recipe,
    )
    parser.add_argument(
        "--consistency-weight",
        "--lambda",
        type=NON_NEGATIVE,
        default=_default(cls, "consistency_weight") if cls else None,
        dest="consistency_weight",
        help="lambda, the weight of the one-step (consistency) loss" + recipe,
    )
    parser.add_argument(
        "--target",
        choices=targets(),
        default=_default(cls, "target") if cls else None,
        help="SnapFlow's one-step target: the average of Euler velocities, or bootstrapped from the model's own half-jumps"
        + recipe,
    )
    parser.add_argument(
        "--target-steps",
        type=_target_steps,
        default=_default(cls, "target_steps") if cls else None,
        help="Euler steps the target spans (2: the paper); a schedule such as 2,4,8 splits training into equal stages"
        + recipe,
    )


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="snapflow",
        description="One-step action generation for flow-matching policies.",
        formatter_class=_HelpFormatter,
    )
    parser.add_argument("--version", action="version", version=f"snapflow {version('snapflow')}")
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument("--no-progress", action="store_true", help="hide progress bars")
    common.add_argument(
        "--threads",
        type=COUNT,
        help="torch CPU threads (default: torch's, one per core; give 1 where other jobs share the cores: "
        "multi-threaded ops then wait on each other's time slices, ten times slower or worse)",
    )
    commands = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    toy = _command(
        commands,
        "toy",
        "distill a 2-D conditional mixture and compare 10-step, naive 1-step, SnapFlow 1-step",
        _toy,
        _nothing_written,
        common,
    )
    toy.add_argument("--seed", type=NON_NEGATIVE_COUNT, default=ToyConfig.seed, help="seed of data, models and noise")
    toy.add_argument(
        "--teacher-steps", type=COUNT, default=ToyConfig.teacher_steps, help="flow-matching training steps"
    )
    toy.add_argument("--distill-steps", type=COUNT, default=ToyConfig.distill_steps, help="distillation steps")
    _add_objective_options(toy, ToyConfig)
    _add_output(toy, "outputs/toy", "where the PNG and JSON go")

    compare = _command(
        commands,
        "toy-compare",
        "SnapFlow's one-step targets on the toy mixture, over seeds",
        _toy_compare,
        _runs_kept,
        common,
    )
    compare.add_argument(
        "--targets",
        nargs="+",
        type=_target_option,
        default=[TargetOption.parse(text) for text in ("euler:2", "euler:4", "euler:8")],
        help="TARGET:STEPS options, the first the reference: euler:8, euler:2,4,8 (a schedule), bootstrap:8",
    )
    compare.add_argument("--seeds", nargs="+", type=NON_NEGATIVE_COUNT, default=[0, 1, 2], help="seeds of every run")
    compare.add_argument(
        "--teacher-steps", type=COUNT, default=ToyConfig.teacher_steps, help="flow-matching training steps"
    )
    compare.add_argument("--distill-steps", type=COUNT, default=ToyConfig.distill_steps, help="distillation steps")
    compare.add_argument(
        "--consistency-weight",
        "--lambda",
        type=NON_NEGATIVE,
        default=ToyConfig.consistency_weight,
        dest="consistency_weight",
        help="lambda, the weight of the one-step (consistency) loss",
    )
    compare.add_argument("--workers", type=COUNT, default=1, help="runs in parallel, each on cores / workers threads")
    _add_output(compare, "outputs/toy-compare", "where runs, JSON, table and PNG go (finished runs are reused)")

    collect = _command(
        commands, "collect", "expert demonstrations (successful episodes only)", _collect, _collect_interrupted, common
    )
    collect.add_argument(
        "--env",
        choices=list(BENCHMARKS),
        default=DEFAULT_BENCHMARK,
        help="benchmark; metaworld-via-points routes each episode through one of two via-points (multimodal)",
    )
    collect.add_argument("--tasks", help=TASKS_HELP)
    collect.add_argument("--episodes", type=COUNT, default=EPISODES_PER_TASK, help="successful episodes per task")
    collect.add_argument(
        "--image-size",
        type=COUNT,
        help="also store camera images of this size (rendered off-screen with MUJOCO_GL=egl or osmesa)",
    )
    _add_output(collect, None, "demonstrations directory (npz + meta.json)")
    collect.add_argument(
        "--lerobot-dataset",
        metavar="ROOT",
        help="also write them as a LeRobotDataset at this (new) root, with LeRobot's writer (needs snapflow[lerobot])",
    )
    collect.add_argument("--repo-id", help="the LeRobotDataset's repo id (default: local/<ROOT's folder name>)")

    experts = _command(
        commands, "experts", "the benchmark's scripted experts' success per task", _experts, _nothing_written, common
    )
    experts.add_argument("--env", choices=list(BENCHMARKS), default=DEFAULT_BENCHMARK, help="benchmark")
    experts.add_argument("--tasks", help=TASKS_HELP)
    experts.add_argument("--split", choices=list(SPLITS), default="eval", help="whose variations the experts run on")
    experts.add_argument("--episodes", type=COUNT, default=50, help="episodes per task (one per variation)")
    experts.add_argument("--workers", type=COUNT, default=1, help="tasks run side by side, one process each")
    _add_output(experts, "outputs/experts", "where experts.json and experts.md go")

    train = _command(
        commands,
        "train",
        "train a built-in flow-matching teacher on demonstrations",
        _train,
        _training_interrupted,
        common,
    )
    _add_training_options(train, TEACHER_TRAINING, data_required=False)
    train.add_argument(
        "--policy",
        choices=[*POLICIES, *LEROBOT_TEACHERS],
        default=next(iter(POLICIES)),
        help="built-in policy (with --data), or smolvla: LeRobot's SmolVLAPolicy from scratch (with --dataset)",
    )
    train.add_argument("--dataset", help="smolvla: LeRobotDataset root directory on disk, or repo id")
    train.add_argument("--repo-id", help="repo id of a dataset given as a directory (default: local/<folder name>)")
    train.add_argument(
        "--smolvlm", choices=list(SMOLVLM_SIZES), default="small", help="smolvla: the size of its SmolVLM"
    )
    train.add_argument(
        "--n-action-steps", type=COUNT, default=4, help="smolvla: actions LeRobot's select_action runs per chunk"
    )
    train.add_argument(
        "--chunk-length", type=COUNT, help="actions per predicted chunk (default: the policy's; smolvla 8)"
    )
    train.add_argument("--use-image", action="store_true", help="minivla: read the demonstrations' camera images")
    train.add_argument("--image-size", type=COUNT, help="minivla with --use-image, smolvla: the images' size")
    train.add_argument(
        "--state-dim", type=COUNT, help="read only the leading entries of the state (4: hand and gripper; default all)"
    )
    train.add_argument(
        "--val-fraction",
        type=_validation_share,
        default=VAL_FRACTION,
        help="share of each task's episodes held out, in [0, 1)",
    )

    distill = _command(
        commands,
        "distill",
        "SnapFlow-distill a teacher into a 1-NFE student",
        _distill,
        _training_interrupted,
        common,
    )
    # no parser defaults: the recipe's, and a LeRobot policy trains with the paper's settings
    _add_training_options(distill, None, data_required=False)
    distill.add_argument(
        "--recipe",
        choices=list(RECIPES),
        help="the student's settings, each overridden by the options below: "
        + "; ".join(f"{name}: {recipe.summary}" for name, recipe in RECIPES.items())
        + f" (default: {DEFAULT_RECIPE} for a built-in teacher, {LEROBOT_RECIPE} for a LeRobot policy)",
    )
    distill.add_argument("--teacher", help="teacher run or checkpoint directory (built-in policy)")
    distill.add_argument("--policy", help="LeRobot pi0, pi0.5 or SmolVLA: hub id or local pretrained directory")
    distill.add_argument("--dataset", help="LeRobotDataset: root directory on disk, or repo id")
    distill.add_argument("--repo-id", help="repo id of a dataset given as a directory (default: local/<folder name>)")
    distill.add_argument("--alpha", type=SHARE, default=None, help="flow-matching share of each batch")
    distill.add_argument(
        "--clamp",
        type=POSITIVE,
        default=None,
        help="bound on the no-grad teacher velocities (default: the recipe's, none in both)",
    )
    distill.add_argument(
        "--train-prefix", action="store_true", help="also train the prefix encoder (frozen by default)"
    )
    distill.add_argument(
        "--teacher-velocity",
        choices=TEACHER_VELOCITIES,
        default=None,
        help="snapflow's consistency target from the model's marginal velocity, or eps - a (ablation; default: the "
        "recipe's)",
    )
    distill.add_argument("--no-target-time", action="store_true", help="ablation: no target-time embedding phi_s")
    distill.add_argument(
        "--intermediate-jumps",
        type=SHARE,
        default=None,
        help="share of the one-step rows that jump between inner times t -> s instead of 1 -> 0 (default: the recipe's)",
    )
    _add_objective_options(distill, None)
    settings_fields = {field.name for field in fields(DistillSettings)}
    own_options = {
        entry.name: [option for option in entry.options if option not in settings_fields]
        for entry in OBJECTIVES.values()
    }
    distill.add_argument(
        "--objective-option",
        type=_objective_option,
        action="append",
        metavar="NAME=VALUE",
        help="an option of the chosen objective that no flag here sets, the value read as in TOML; repeatable ("
        + "; ".join(f"{name}: {', '.join(options)}" for name, options in own_options.items() if options)
        + ")",
    )

    evaluate = _command(
        commands,
        "eval",
        "closed-loop success, offline metrics and latency on a benchmark, "
        "or success of a distilled LeRobot policy in LeRobot's environments",
        _eval,
        _nothing_written,
        common,
    )
    evaluate.add_argument(
        "--policy",
        required=True,
        nargs="+",
        help="run or checkpoint directories, or LeRobot policy folders (run/lerobot_policy); PATH=MODES runs "
        "only those modes of that one, e.g. teacher/lerobot_policy=teacher-10,naive student/lerobot_policy=snapflow-1 "
        "(with --lerobot-env: one distilled LeRobot policy directory)",
    )
    evaluate.add_argument(
        "--modes",
        type=_modes,
        default=_modes("teacher-10,naive,snapflow-1"),
        help="comma-separated: teacher-N, naive, snapflow-N (snapflow-N needs a distilled policy)",
    )
    evaluate.add_argument(
        "--env",
        choices=list(BENCHMARKS),
        help="benchmark (default: the one the first policy's demonstrations came from)",
    )
    evaluate.add_argument("--tasks", help=TASKS_HELP)
    evaluate.add_argument("--episodes", type=COUNT, default=10, help="episodes per task")
    evaluate.add_argument(
        "--n-act",
        "--n-action-steps",
        type=COUNT,
        dest="n_act",
        help=f"actions executed per predicted chunk (default: {N_ACT}; with --lerobot-env the policy's own)",
    )
    evaluate.add_argument("--data", help="demonstrations for offline metrics on the held-out episodes")
    evaluate.add_argument(
        "--seed", type=NON_NEGATIVE_COUNT, help="evaluation seed (default: 0; with --lerobot-env LeRobot's 1000)"
    )
    evaluate.add_argument(
        "--compile",
        choices=COMPILE_MODES,
        help="the fast path: torch.compile each policy's prefix pass and one-pass velocity (snapflow.inference)",
    )
    evaluate.add_argument(
        "--lerobot-env", help="evaluate in LeRobot's environment of this type (pusht, aloha, libero, metaworld, ...)"
    )
    evaluate.add_argument("--env-task", help="with --lerobot-env: the task or suite (default: the environment's own)")
    evaluate.add_argument(
        "--n-envs", type=COUNT, default=1, help="with --lerobot-env: environments stepped in parallel"
    )
    evaluate.add_argument(
        "--max-episode-steps", type=COUNT, help="with --lerobot-env: cut episodes short of the environment's limit"
    )
    _add_output(evaluate, "outputs/eval", "where report.json, report.md and the plots go")

    diagnose = _command(
        commands,
        "diagnose",
        "where a one-step student fails on a task: distance to the scripted expert along the episodes, and every "
        "row's chunks at the failed moments against the nearest demonstration",
        _diagnose,
        _nothing_written,
        common,
    )
    diagnose.add_argument("--teacher", required=True, help="the teacher's run or checkpoint directory")
    diagnose.add_argument("--student", required=True, help="the distilled student's run or checkpoint directory")
    diagnose.add_argument("--task", required=True, help="one task of the benchmark, e.g. peg-insert-side-v3")
    diagnose.add_argument("--env", choices=list(BENCHMARKS), help="benchmark (default: the student's)")
    diagnose.add_argument("--data", help="demonstrations (default: those the student was distilled on)")
    diagnose.add_argument("--episodes", type=COUNT, default=20, help="evaluation episodes of the task")
    diagnose.add_argument("--n-act", type=COUNT, default=N_ACT, help="actions executed per predicted chunk")
    diagnose.add_argument("--teacher-steps", type=COUNT, default=10, help="Euler steps of the teacher row")
    diagnose.add_argument("--seed", type=NON_NEGATIVE_COUNT, default=0, help="seed of the sampling noise")
    _add_output(diagnose, "outputs/diagnosis", "folder for diagnosis.json, diagnosis.md and the PNGs")

    bench = _command(
        commands,
        "bench",
        "batch-1 latency at NFE 10, 5, 2, 1: prefix, denoising, end-to-end, speedups",
        _bench,
        _nothing_written,
        common,
    )
    subject = bench.add_mutually_exclusive_group(required=True)
    subject.add_argument(
        "--policy", help="built-in checkpoint or run directory, distilled LeRobot folder, or LeRobot hub id / folder"
    )
    subject.add_argument(
        "--architecture", choices=architectures(), help="random weights at full size (minivla: the demo's policy)"
    )
    bench.add_argument(
        "--vlm", help="smolvla: folder (or hub id) of its VLM's config and processor (no weights are loaded)"
    )
    bench.add_argument("--device", help="cpu, cuda, cuda:1, ... (default: cuda when available)")
    bench.add_argument(
        "--dtype", choices=["float32", "bfloat16", "float16"], default="float32", help="weights and activations"
    )
    bench.add_argument(
        "--compile",
        choices=COMPILE_MODES,
        help="the fast path: torch.compile the prefix pass and the one-pass action expert (reduce-overhead: both "
        "captured as CUDA graphs on a GPU)",
    )
    bench.add_argument("--warmup", type=NON_NEGATIVE_COUNT, default=10, help="untimed calls of each quantity first")
    bench.add_argument("--repeats", type=COUNT, default=50, help="timed calls of each quantity, round-robin")
    bench.add_argument("--no-profile", action="store_true", help="skip the torch.profiler table of the 1-NFE path")
    bench.add_argument(
        "--distill-batch-sizes",
        type=_counts,
        help="also time a distillation step (the paper's objective, AdamW on the expert) and its peak memory at "
        "these batch sizes, e.g. 4,32",
    )
    bench.add_argument(
        "--vision-dtype",
        choices=["bfloat16"],
        help="pi0 / pi0.5: run the vision tower in this dtype (LeRobot keeps it in float32); reports how far actions move",
    )
    bench.add_argument(
        "--tf32",
        action="store_true",
        help="float32 matrix products in TF32 where the GPU has it (off in LeRobot); reports how far actions move",
    )
    bench.add_argument(
        "--batch-sizes",
        type=_counts,
        default=(1, 8, 32),
        help="throughput of the 10-step teacher and the one-step mode at these batch sizes (comma-separated)",
    )
    _add_output(bench, "outputs/bench", "where bench.json, bench.md and the plot go")

    export = _command(
        commands,
        "export",
        "export a one-step student as one ONNX graph (prefix and jump, no sampling loop)",
        _export,
        _nothing_written,
        common,
    )
    export.add_argument(
        "--policy", required=True, help="student checkpoint or run directory, or distilled LeRobot folder"
    )
    export.add_argument("--format", choices=list(EXPORT_FORMATS), default="onnx", help="the exported format")
    _add_output(export, None, "folder for model.onnx and policy.json (snapflow eval / bench load it)")

    targets = _command(
        commands,
        "bench-targets",
        "seconds per distillation step of each SnapFlow target (built-in policy)",
        _bench_targets,
        _nothing_written,
        common,
    )
    targets.add_argument("--teacher", required=True, help="teacher run or checkpoint directory (built-in policy)")
    targets.add_argument("--data", required=True, help="its demonstrations")
    targets.add_argument(
        "--targets",
        nargs="+",
        type=_target_option,
        default=[TargetOption.parse(text) for text in ("euler:2", "euler:4", "euler:8", "bootstrap:8")],
        help="TARGET:STEPS options, the first the reference: euler:8, euler:2,4,8 (a schedule), bootstrap:8",
    )
    targets.add_argument("--batch-size", type=COUNT, default=64, help="training pairs per timed step")
    targets.add_argument("--warmup", type=NON_NEGATIVE_COUNT, default=5, help="untimed steps of each target first")
    targets.add_argument("--repeats", type=COUNT, default=30, help="timed steps of each target")
    _add_output(targets, "outputs/bench-targets", "where training_cost.json and .md go")

    sweep = _command(
        commands,
        "sweep",
        "run sweep configs (seeds, ablations, baselines) and write their results",
        _sweep,
        _runs_kept,
        common,
    )
    sweep.add_argument("configs", nargs="+", help="sweep TOML files, e.g. configs/sweeps/mt10-state.toml")
    sweep.add_argument(
        "--workers", type=COUNT, default=1, help="jobs run side by side, each on cores / workers threads"
    )
    sweep.add_argument(
        "--document", help="also write the tables between their markers in this Markdown file (e.g. docs/RESULTS.md)"
    )
    sweep.add_argument("--report-only", action="store_true", help="only rebuild the results from finished runs")
    sweep.add_argument(
        "--tables",
        type=lambda text: text.split(","),
        help="comma-separated: run and rebuild only these tables; the others keep their results in results.json "
        "(default: every table)",
    )

    demo = _command(
        commands, "demo", "MT10: collect -> train -> distill -> eval, one final table", _demo, _demo_interrupted, common
    )
    demo.add_argument("--full", action="store_true", help="stronger, longer preset")
    demo.add_argument(
        "--recipe",
        choices=list(RECIPES),
        default=DEFAULT_RECIPE,
        help="the student's recipe: " + "; ".join(f"{name}: {recipe.summary}" for name, recipe in RECIPES.items()),
    )
    demo.add_argument("--resume", action="store_true", help="continue an interrupted demo in the same output directory")
    _add_output(demo, "outputs/demo", "where the data, runs, report and plots go")
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    prefix = f"snapflow {args.command}:"
    if args.threads:
        import torch

        torch.set_num_threads(args.threads)
    try:
        return args.run(args)
    except (ValueError, TypeError, FileNotFoundError, FileExistsError) as error:
        print(f"{prefix} error: {error}", file=sys.stderr)
    except ModuleNotFoundError as error:
        module = (error.name or "").partition(".")[0]
        if module not in EXTRAS:
            raise
        print(
            f'{prefix} error: this needs {module}, which is not installed: pip install "snapflow[{EXTRAS[module]}]"',
            file=sys.stderr,
        )
    except OSError as error:  # after the named cases above: a disk full, a folder made read-only mid-run, ...
        print(f"{prefix} error: {error.strerror or error}: {error.filename}", file=sys.stderr)
    except KeyboardInterrupt:
        print(f"{prefix} {args.interrupted(args)}", file=sys.stderr)
        return INTERRUPTED
    return 2


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


if __name__ == "__main__":
    entry_point()
