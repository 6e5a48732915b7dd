"""The ``snapflow`` command line: one sub-command per job, each a thin shell over the Python API.

Defaults and choices are read from the settings dataclasses and the registries, never restated here.
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import MISSING, fields, replace
from pathlib import Path
from typing import Any

from snapflow.data.collect import EPISODES_PER_TASK
from snapflow.envs.factory import BENCHMARKS, DEFAULT_BENCHMARK, make_benchmark
from snapflow.inference.compile import COMPILE_MODES
from snapflow.jobs.toy import ToyConfig
from snapflow.objective.snapflow import TEACHER_VELOCITIES
from snapflow.policies.factory import POLICIES
from snapflow.reporting.files import write_json, write_text
from snapflow.reporting.tables import markdown_table
from snapflow.training.distill import METHODS, TARGETS, DistillSettings, TargetOption, parse_target_steps
from snapflow.training.recipes import STUDENT_TRAINING, TEACHER_TRAINING, VAL_FRACTION
from snapflow.training.trainer import TrainConfig

TRAINING_OPTIONS = ("steps", "batch_size", "learning_rate", "seed")


def _default(cls: type, name: str) -> Any:
    field = next(field for field in fields(cls) if field.name == name)
    return field.default if field.default is not MISSING else field.default_factory()


def _tasks(benchmark_name: str, value: str) -> list[str]:
    benchmark = make_benchmark(benchmark_name)
    return (
        list(benchmark.tasks)
        if value == "all"
        else benchmark.check_tasks([task.strip() for task in value.split(",") if task.strip()])
    )


def _toy(args: argparse.Namespace) -> int:
    from snapflow.jobs.toy import plot_toy_result, run_toy_experiment

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

    naive = result.distances["naive-1"]
    student = "SnapFlow 1-NFE" if config.method == "snapflow" else f"{config.method} 1-NFE"
    rows = [("teacher 10-NFE", "teacher-10", 10), ("naive 1-NFE", "naive-1", 1), (student, "snapflow-1", 1)]
    print(
        f"\nConditional Gaussian mixture, seed {config.seed}: {config.eval_contexts} contexts x "
        f"{config.samples_per_context} samples, energy distance to exact samples (lower is better)\n"
    )
    print(
        markdown_table(
            ["sampler", "NFE", "energy distance", "/ naive 1-NFE"],
            [
                [label, nfe, f"{result.distances[key]:.4f}", f"{result.distances[key] / naive:.3f}"]
                for label, key, nfe in rows
            ],
        )
    )
    print(f"\ntrained and evaluated in {elapsed:.1f} s ({1000 * result.distill_step_s:.1f} ms per distillation step)")

    output = Path(args.output_dir)
    plot_toy_result(result, output / "toy_samples.png")
    write_json(output / "toy_results.json", {**result.to_dict(), "wall_time_s": round(elapsed, 2)})
    print(f"wrote {output / 'toy_samples.png'} and {output / 'toy_results.json'}")
    return 0


def _toy_compare(args: argparse.Namespace) -> int:
    from snapflow.jobs.toy_compare import compare_targets, markdown_comparison

    options = [TargetOption.parse(text) for text in args.targets]
    base = ToyConfig(
        teacher_steps=args.teacher_steps, distill_steps=args.distill_steps, consistency_weight=args.consistency_weight
    )
    started = time.perf_counter()
    summary = compare_targets(options, args.seeds, base, args.output_dir, args.workers, not args.no_progress)
    print(markdown_comparison(summary))
    print(
        f"\ndone in {(time.perf_counter() - started) / 60:.1f} min; wrote comparison.json, comparison.md and comparison.png to {args.output_dir}"
    )
    return 0


def _collect(args: argparse.Namespace) -> int:
    from snapflow.data.collect import collect

    demonstrations = collect(
        make_benchmark(args.env),
        _tasks(args.env, args.tasks),
        args.episodes,
        args.output,
        args.image_size,
        not args.no_progress,
    )
    print(
        f"wrote {len(demonstrations.episodes)} successful expert episodes ({len(demonstrations.states)} steps) to {args.output}"
    )
    return 0


def _train_config(args: argparse.Namespace, base: TrainConfig) -> TrainConfig:
    return replace(base, **{name: getattr(args, name) for name in TRAINING_OPTIONS if getattr(args, name) is not None})


def _train(args: argparse.Namespace) -> int:
    from snapflow.data.demonstrations import Demonstrations
    from snapflow.policies.factory import default_config
    from snapflow.training.recipes import train_teacher

    demonstrations = Demonstrations.load(args.data)
    overrides = {
        name: getattr(args, name) for name in ("chunk_length", "image_size") if getattr(args, name) is not None
    }
    if args.use_image:
        overrides["use_image"] = True
    policy = default_config(
        args.policy,
        args.state_dim or demonstrations.states.shape[1],
        demonstrations.actions.shape[1],
        list(demonstrations.instructions.values()),
        **overrides,
    )
    state = train_teacher(
        args.data,
        args.output,
        policy,
        _train_config(args, TEACHER_TRAINING),
        args.val_fraction,
        args.resume,
        not args.no_progress,
    )
    print(f"teacher trained to step {state['step']} in {state['wall_time_s']:.0f} s; checkpoints in {args.output}")
    return 0


def _distill(args: argparse.Namespace) -> int:
    settings = DistillSettings(
        alpha=args.alpha,
        consistency_weight=args.consistency_weight,
        teacher_velocity_clamp=args.clamp,
        freeze_prefix=not args.train_prefix,
        method=args.method,
        teacher_velocity=args.teacher_velocity,
        target_time=not args.no_target_time,
        target=args.target,
        target_steps=args.target_steps,
    )
    built_in = bool(args.teacher and args.data) and not (args.policy or args.dataset)
    lerobot = bool(args.policy and args.dataset) and not (args.teacher or args.data)
    if not (built_in or lerobot):
        raise ValueError("give either --teacher and --data (a built-in policy) or --policy and --dataset (LeRobot)")
    if lerobot:
        from snapflow.training.lerobot import EXPORT_DIRECTORY, distill_lerobot, paper_training

        local = Path(args.dataset).is_dir()  # a dataset root on disk, or else a repo id LeRobot fetches and caches
        repo_id = (args.repo_id or f"local/{Path(args.dataset).name}") if local else args.dataset
        state = distill_lerobot(
            args.policy,
            args.dataset if local else None,
            repo_id,
            args.output,
            _train_config(args, paper_training()),
            settings,
            args.resume,
            not args.no_progress,
        )
        print(
            f"SnapFlow student trained to step {state['step']}; LeRobot policy in {Path(args.output) / EXPORT_DIRECTORY}"
        )
        return 0
    from snapflow.training.recipes import distill

    state = distill(
        args.teacher,
        args.data,
        args.output,
        _train_config(args, STUDENT_TRAINING),
        settings,
        resume=args.resume,
        progress=not args.no_progress,
    )
    print(
        f"SnapFlow student trained to step {state['step']} in {state['wall_time_s']:.0f} s; checkpoints in {args.output}"
    )
    return 0


def _eval(args: argparse.Namespace) -> int:
    from snapflow.evaluation.pipeline import N_ACT, evaluate
    from snapflow.evaluation.report import markdown_report, write_report
    from snapflow.flow.solver import SamplingMode
    from snapflow.inference.compile import compile_policy
    from snapflow.policies.checkpoint import load_policy

    modes = [SamplingMode.parse(name) for name in args.modes.split(",")]
    if args.lerobot_env:
        return _eval_in_lerobot_env(args, modes)
    loaded = {path: load_policy(path) for path in args.policy}
    if args.compile:
        for policy in loaded.values():
            compile_policy(policy.policy, args.compile)
    # the benchmark the first policy's demonstrations came from, unless named
    env = args.env or next(iter(loaded.values())).metadata.get("data", {}).get("env", DEFAULT_BENCHMARK)
    runs = [
        (f"{mode.name}" if len(loaded) == 1 else f"{Path(path).name} {mode.name}", policy, mode)
        for path, policy in loaded.items()
        for mode in modes
    ]
    report = evaluate(
        runs,
        make_benchmark(env),
        _tasks(env, args.tasks),
        args.episodes,
        args.n_act or N_ACT,
        args.data,
        seed=args.seed if args.seed is not None else 0,
        progress=not args.no_progress,
    )
    write_report(report, args.output_dir)
    print(markdown_report(report))
    print(f"wrote report.json, report.md and PNG plots to {args.output_dir}")
    return 0


def _eval_in_lerobot_env(args: argparse.Namespace, modes: list) -> int:
    from snapflow.evaluation.lerobot_env import evaluate_in_lerobot_env, lerobot_eval_table, write_lerobot_eval

    if len(args.policy) != 1:
        raise ValueError("--lerobot-env evaluates one distilled LeRobot policy directory at a time")
    report = evaluate_in_lerobot_env(
        args.policy[0],
        args.lerobot_env,
        modes,
        args.episodes,
        args.env_task,
        args.n_act,
        args.n_envs,
        args.seed if args.seed is not None else 1000,
        args.max_episode_steps,
        compile_mode=args.compile,
    )
    write_lerobot_eval(report, args.output_dir)
    print(lerobot_eval_table(report))
    print(f"wrote report.json, report.md and each mode's eval_info.json to {args.output_dir}")
    return 0


def _bench(args: argparse.Namespace) -> int:
    import torch

    from snapflow.benchmark.bench import markdown_bench, run_bench, write_bench
    from snapflow.benchmark.subjects import make_subject

    if args.threads:
        torch.set_num_threads(args.threads)
    device = torch.device(args.device or ("cuda" if torch.cuda.is_available() else "cpu"))
    dtype = {"float32": torch.float32, "bfloat16": torch.bfloat16, "float16": torch.float16}[args.dtype]
    subject = make_subject(args.policy, args.architecture, device, dtype, args.vlm)
    report = run_bench(subject, args.warmup, args.repeats, args.compile, profile=not args.no_profile)
    write_bench(report, args.output_dir)
    print(markdown_bench(report))
    print(
        f"wrote bench.json, bench.md, latency.png{'' if args.no_profile else ' and profile.txt'} to {args.output_dir}"
    )
    return 0


def _bench_targets(args: argparse.Namespace) -> int:
    import torch

    from snapflow.benchmark.training_cost import checkpoint_training_cost, markdown_training_cost

    if args.threads:
        torch.set_num_threads(args.threads)
    options = [TargetOption.parse(text) for text in args.targets]
    result = checkpoint_training_cost(args.teacher, args.data, options, args.batch_size, args.warmup, args.repeats)
    table = markdown_training_cost(result)
    output = Path(args.output_dir)
    write_json(output / "training_cost.json", {**result, "teacher": str(args.teacher), "data": str(args.data)})
    write_text(output / "training_cost.md", table + "\n")
    print(table)
    print(f"wrote training_cost.json and training_cost.md to {output}")
    return 0


def _sweep(args: argparse.Namespace) -> int:
    from snapflow.jobs.sweep import load_sweep, run_sweeps, write_results

    configs = [load_sweep(path) for path in args.configs]
    if not args.report_only:
        run_sweeps(configs, args.workers, not args.no_progress)
    for config in configs:
        write_results(config, args.document)
        print(f"{config.name}: wrote results.json, tables.md and PNG plots to {config.results_dir}")
    if args.document:
        print(f"updated the sweep tables in {args.document}")
    return 0


def _demo(args: argparse.Namespace) -> int:
    from snapflow.evaluation.report import markdown_report
    from snapflow.jobs.demo import PRESETS, run_demo

    report = run_demo(PRESETS["full" if args.full else "fast"], args.output_dir, not args.no_progress, args.resume)
    print(markdown_report(report))
    print(f"wrote report.json, report.md and PNG plots to {args.output_dir}")
    return 0


def _add_training_options(parser: argparse.ArgumentParser, base: TrainConfig, data_required: bool = True) -> None:
    """``--steps``, ``--batch-size``, ``--learning-rate``, ``--seed``: TrainConfig fields, defaults from ``base``."""
    parser.add_argument("--data", required=data_required, help="demonstrations directory written by `snapflow collect`")
    parser.add_argument("--output", required=True, help="run directory for checkpoints")
    for name in TRAINING_OPTIONS:
        parser.add_argument(
            f"--{name.replace('_', '-')}", type=type(getattr(base, name)), help=f"default {getattr(base, name)}"
        )
    parser.add_argument("--resume", action="store_true", help="continue from the run's latest checkpoint")


def _target_steps(value: str) -> int | tuple[int, ...]:
    try:
        return parse_target_steps(value)
    except ValueError as error:
        raise argparse.ArgumentTypeError(str(error)) from None


def _add_objective_options(parser: argparse.ArgumentParser, cls: type) -> None:
    """``--method``, ``--lambda``, ``--target`` and ``--target-steps`` with the defaults of the dataclass ``cls``
    (DistillSettings or ToyConfig)."""
    parser.add_argument(
        "--method",
        choices=METHODS,
        default=_default(cls, "method"),
        help="distillation objective (the others are baselines)",
    )
    parser.add_argument(
        "--consistency-weight",
        "--lambda",
        type=float,
        default=_default(cls, "consistency_weight"),
        dest="consistency_weight",
    )
    parser.add_argument(
        "--target",
        choices=TARGETS,
        default=_default(cls, "target"),
        help="SnapFlow's one-step target: the average of Euler velocities, or bootstrapped from the model's own half-jumps",
    )
    parser.add_argument(
        "--target-steps",
        type=_target_steps,
        default=_default(cls, "target_steps"),
        help="Euler steps the target spans (2: the paper); a schedule such as 2,4,8 splits training into equal stages",
    )


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="snapflow", description="One-step action generation for flow-matching policies."
    )
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument("--no-progress", action="store_true", help="hide progress bars")
    commands = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    toy = commands.add_parser(
        "toy",
        parents=[common],
        help="distill a 2-D conditional mixture and compare 10-step, naive 1-step, SnapFlow 1-step",
    )
    toy.add_argument("--seed", type=int, default=ToyConfig.seed)
    toy.add_argument("--teacher-steps", type=int, default=ToyConfig.teacher_steps, help="flow-matching training steps")
    toy.add_argument("--distill-steps", type=int, default=ToyConfig.distill_steps, help="SnapFlow distillation steps")
    _add_objective_options(toy, ToyConfig)
    toy.add_argument("--output-dir", default="outputs/toy", help="where the PNG and JSON go")
    toy.set_defaults(run=_toy)

    compare = commands.add_parser(
        "toy-compare", parents=[common], help="SnapFlow's one-step targets on the toy mixture, over seeds"
    )
    compare.add_argument(
        "--targets",
        nargs="+",
        default=["euler:2", "euler:4", "euler:8"],
        help="TARGET:STEPS options, the first the reference: euler:8, euler:2,4,8 (a schedule), bootstrap:8",
    )
    compare.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2])
    compare.add_argument(
        "--teacher-steps", type=int, default=ToyConfig.teacher_steps, help="flow-matching training steps"
    )
    compare.add_argument("--distill-steps", type=int, default=ToyConfig.distill_steps, help="distillation steps")
    compare.add_argument(
        "--consistency-weight", "--lambda", type=float, default=ToyConfig.consistency_weight, dest="consistency_weight"
    )
    compare.add_argument("--workers", type=int, default=1, help="runs in parallel, each on cores / workers threads")
    compare.add_argument(
        "--output-dir",
        default="outputs/toy-compare",
        help="where runs, JSON, table and PNG go (finished runs are reused)",
    )
    compare.set_defaults(run=_toy_compare)

    collect = commands.add_parser("collect", parents=[common], help="expert demonstrations (successful episodes only)")
    collect.add_argument(
        "--env",
        choices=list(BENCHMARKS),
        default=DEFAULT_BENCHMARK,
        help="benchmark; metaworld-via-points routes each episode through one of two via-points (multimodal)",
    )
    collect.add_argument("--tasks", default="all", help="'all' or comma-separated task names")
    collect.add_argument("--episodes", type=int, default=EPISODES_PER_TASK, help="successful episodes per task")
    collect.add_argument(
        "--image-size",
        type=int,
        help="also store camera images of this size (rendered off-screen with MUJOCO_GL=egl or osmesa)",
    )
    collect.add_argument("--output", required=True)
    collect.set_defaults(run=_collect)

    train = commands.add_parser(
        "train", parents=[common], help="train a built-in flow-matching teacher on demonstrations"
    )
    _add_training_options(train, TEACHER_TRAINING)
    train.add_argument("--policy", choices=list(POLICIES), default=next(iter(POLICIES)), help="built-in policy")
    train.add_argument("--chunk-length", type=int, help="actions per predicted chunk (default: the policy's)")
    train.add_argument("--use-image", action="store_true", help="minivla: read the demonstrations' camera images")
    train.add_argument("--image-size", type=int, help="minivla with --use-image: the images' size")
    train.add_argument(
        "--state-dim", type=int, help="read only the leading entries of the state (4: hand and gripper; default all)"
    )
    train.add_argument(
        "--val-fraction", type=float, default=VAL_FRACTION, help="share of each task's episodes held out"
    )
    train.set_defaults(run=_train)

    distill = commands.add_parser("distill", parents=[common], help="SnapFlow-distill a teacher into a 1-NFE student")
    _add_training_options(distill, STUDENT_TRAINING, data_required=False)
    distill.add_argument("--teacher", help="teacher run or checkpoint directory (built-in policy)")
    distill.add_argument("--policy", help="LeRobot pi0, pi0.5 or SmolVLA: hub id or local pretrained directory")
    distill.add_argument("--dataset", help="LeRobotDataset: root directory on disk, or repo id")
    distill.add_argument("--repo-id", help="repo id of a dataset given as a directory (default: local/<folder name>)")
    distill.add_argument(
        "--alpha", type=float, default=_default(DistillSettings, "alpha"), help="flow-matching share of each batch"
    )
    distill.add_argument(
        "--clamp",
        type=float,
        default=_default(DistillSettings, "teacher_velocity_clamp"),
        help="bound on the no-grad teacher velocities",
    )
    distill.add_argument(
        "--train-prefix", action="store_true", help="also train the prefix encoder (frozen by default)"
    )
    distill.add_argument(
        "--teacher-velocity",
        choices=TEACHER_VELOCITIES,
        default=_default(DistillSettings, "teacher_velocity"),
        help="snapflow's consistency target from the model's marginal velocity (default) or eps - a (ablation)",
    )
    distill.add_argument("--no-target-time", action="store_true", help="ablation: no target-time embedding phi_s")
    _add_objective_options(distill, DistillSettings)
    distill.set_defaults(run=_distill)

    evaluate = commands.add_parser(
        "eval",
        parents=[common],
        help="closed-loop success, offline metrics and latency on a benchmark, "
        "or success of a distilled LeRobot policy in LeRobot's environments",
    )
    evaluate.add_argument(
        "--policy",
        required=True,
        nargs="+",
        help="run or checkpoint directories (with --lerobot-env: "
        "one distilled LeRobot policy directory, e.g. run/lerobot_policy)",
    )
    evaluate.add_argument(
        "--modes", default="teacher-10,naive,snapflow-1", help="comma-separated: teacher-N, naive, snapflow-N"
    )
    evaluate.add_argument(
        "--env",
        choices=list(BENCHMARKS),
        help="benchmark (default: the one the first policy's demonstrations came from)",
    )
    evaluate.add_argument("--tasks", default="all", help="the benchmark's tasks: 'all' or comma-separated names")
    evaluate.add_argument("--episodes", type=int, default=10, help="episodes per task")
    evaluate.add_argument(
        "--n-act",
        "--n-action-steps",
        type=int,
        dest="n_act",
        help="actions executed per predicted chunk (default 4; with --lerobot-env the policy's own)",
    )
    evaluate.add_argument("--data", help="demonstrations for offline metrics on the held-out episodes")
    evaluate.add_argument("--seed", type=int, help="evaluation seed (default 0; with --lerobot-env LeRobot's 1000)")
    evaluate.add_argument(
        "--compile", choices=COMPILE_MODES, help="torch.compile the policies' one-pass velocity (snapflow.inference)"
    )
    evaluate.add_argument(
        "--lerobot-env", help="evaluate in LeRobot's environment of this type (pusht, aloha, libero, metaworld, ...)"
    )
    evaluate.add_argument("--env-task", help="with --lerobot-env: the task or suite (default: the environment's own)")
    evaluate.add_argument("--n-envs", type=int, default=1, help="with --lerobot-env: environments stepped in parallel")
    evaluate.add_argument(
        "--max-episode-steps", type=int, help="with --lerobot-env: cut episodes short of the environment's limit"
    )
    evaluate.add_argument("--output-dir", default="outputs/eval")
    evaluate.set_defaults(run=_eval)

    from snapflow.benchmark.subjects import architectures

    bench = commands.add_parser(
        "bench", parents=[common], help="batch-1 latency at NFE 10, 5, 2, 1: prefix, denoising, end-to-end, speedups"
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
    bench.add_argument("--dtype", choices=["float32", "bfloat16", "float16"], default="float32")
    bench.add_argument(
        "--compile",
        choices=COMPILE_MODES,
        help="torch.compile the one-pass action expert (reduce-overhead: CUDA-graph capture on a GPU)",
    )
    bench.add_argument("--threads", type=int, help="CPU threads (torch.set_num_threads)")
    bench.add_argument("--warmup", type=int, default=10, help="untimed calls of each quantity first")
    bench.add_argument("--repeats", type=int, default=50, help="timed calls of each quantity, round-robin")
    bench.add_argument("--no-profile", action="store_true", help="skip the torch.profiler table of the 1-NFE path")
    bench.add_argument("--output-dir", default="outputs/bench")
    bench.set_defaults(run=_bench)

    targets = commands.add_parser(
        "bench-targets",
        parents=[common],
        help="seconds per distillation step of each SnapFlow target (built-in policy)",
    )
    targets.add_argument("--teacher", required=True, help="teacher run or checkpoint directory (built-in policy)")
    targets.add_argument("--data", required=True, help="its demonstrations")
    targets.add_argument(
        "--targets",
        nargs="+",
        default=["euler:2", "euler:4", "euler:8", "bootstrap:8"],
        help="TARGET:STEPS options, the first the reference: euler:8, euler:2,4,8 (a schedule), bootstrap:8",
    )
    targets.add_argument("--batch-size", type=int, default=64)
    targets.add_argument("--warmup", type=int, default=5)
    targets.add_argument("--repeats", type=int, default=30)
    targets.add_argument("--threads", type=int, help="torch CPU threads (default: torch's choice)")
    targets.add_argument("--output-dir", default="outputs/bench-targets")
    targets.set_defaults(run=_bench_targets)

    sweep = commands.add_parser(
        "sweep", parents=[common], help="run sweep configs (seeds, ablations, baselines) and write their results"
    )
    sweep.add_argument("configs", nargs="+", help="sweep TOML files, e.g. configs/sweeps/mt10-state.toml")
    sweep.add_argument("--workers", type=int, default=1, help="jobs run side by side, each on cores / workers threads")
    sweep.add_argument(
        "--document", help="also write the tables between their markers in this Markdown file (e.g. docs/RESULTS.md)"
    )
    sweep.add_argument("--report-only", action="store_true", help="only rebuild the results from finished runs")
    sweep.set_defaults(run=_sweep)

    demo = commands.add_parser(
        "demo", parents=[common], help="MT10: collect -> train -> distill -> eval, one final table"
    )
    demo.add_argument("--full", action="store_true", help="stronger, longer preset")
    demo.add_argument("--resume", action="store_true", help="continue an interrupted demo in the same output directory")
    demo.add_argument("--output-dir", default="outputs/demo")
    demo.set_defaults(run=_demo)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return args.run(args)
    except (ValueError, TypeError, FileNotFoundError, FileExistsError) as error:
        print(f"snapflow {args.command}: error: {error}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"snapflow {args.command}: interrupted; the last checkpoint is intact (use --resume)", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
