"""``snapflow eval``: closed-loop success, offline metrics and latency of policies on a benchmark, or a distilled
LeRobot policy's success in LeRobot's own environments."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from snapflow.cli.common import (
    COUNT,
    NON_NEGATIVE_COUNT,
    TASKS_HELP,
    add_command,
    add_fast_path,
    add_output,
    argument_type,
    check_writable,
    given,
    nothing_written,
    tasks,
)
from snapflow.envs.factory import BENCHMARKS, DEFAULT_BENCHMARK, make_benchmark
from snapflow.errors import InvalidInputError
from snapflow.evaluation.config import N_ACT
from snapflow.flow.modes import STANDARD_MODES, SamplingMode
from snapflow.flow.realtime_settings import RealTimeChunking

EPISODES = "episodes"  # each row's episode log, in the output folder

_modes = argument_type(lambda text: [SamplingMode.parse(name) for name in text.split(",")])


def add_parser(subparsers: Any) -> None:
    parser = add_command(
        subparsers,
        "eval",
        "closed-loop success, offline metrics and latency on a benchmark, "
        "or success of a distilled LeRobot policy in LeRobot's environments",
        run,
        _interrupted,
    )
    parser.add_argument(
        "--policy",
        required=True,
        nargs="+",
        help="run or checkpoint directories, or LeRobot policy folders (run/lerobot_policy); PATH=MODES runs "
        "only those modes of that one, e.g. teacher/lerobot_policy=teacher-10,naive student/lerobot_policy=snapflow-1 "
        "(with --lerobot-env: one distilled LeRobot policy directory)",
    )
    parser.add_argument(
        "--modes",
        type=_modes,
        default=list(STANDARD_MODES),
        help="comma-separated: teacher-N, teacher (its own number of steps), naive, snapflow-N (snapflow-N needs a "
        "distilled policy)",
    )
    parser.add_argument(
        "--env",
        choices=list(BENCHMARKS),
        help="benchmark (default: the one the first policy's demonstrations came from)",
    )
    parser.add_argument("--tasks", help=TASKS_HELP)
    parser.add_argument("--episodes", type=COUNT, default=10, help="episodes per task")
    parser.add_argument(
        "--first-variation",
        type=NON_NEGATIVE_COUNT,
        default=0,
        help="each task's episodes start from its evaluation variations from this one on (LIBERO: its fixed "
        "initial states, e.g. --first-variation 10 --episodes 10 runs states 10-19; default: the first ones)",
    )
    parser.add_argument(
        "--n-act",
        "--n-action-steps",
        type=COUNT,
        dest="n_act",
        help=f"actions executed per predicted chunk (default: {N_ACT}; with --lerobot-env the policy's own)",
    )
    parser.add_argument(
        "--inference-delay",
        type=NON_NEGATIVE_COUNT,
        metavar="D",
        help="run every episode under an inference delay of D actions (real-time chunking): after the first chunk, "
        "each is planned when D actions of the previous one remain queued, from the observation of that moment, "
        "continuing the previous chunk's rest, and runs its actions D..D+n_act-1 (D <= n_act, n_act + D <= the "
        "chunk length); chunks switch at steps n_act, 2 n_act, ... (default: no delay, no real-time chunking)",
    )
    parser.add_argument(
        "--rtc",
        choices=["guided", "inpaint", "trained"],
        help="with --inference-delay, how a chunk continues the previous one: guided (LeRobot's guided Euler steps; "
        "teacher-N, naive), inpaint (the chunk blended into the previous one along the prefix weights; any mode), "
        "trained (the previous chunk's first D actions given to every pass: a student whose time enters each action, "
        "SmolVLA's or a built-in transformer's, distilled with --rtc-max-delay >= D; a jump's ramp past them then "
        "inpainted) "
        "(default: guided for Euler modes, inpaint for jumps)",
    )
    parser.add_argument(
        "--execution-horizon",
        type=COUNT,
        metavar="H",
        help="with --inference-delay: the new chunk's action at which the prefix weights' linear ramp from 1 "
        "(after the delay) reaches 0 (default: the previous chunk's end)",
    )
    parser.add_argument("--data", help="demonstrations for offline metrics on the held-out episodes")
    parser.add_argument(
        "--seed", type=NON_NEGATIVE_COUNT, help="evaluation seed (default: 0; with --lerobot-env LeRobot's 1000)"
    )
    add_fast_path(parser, "each policy runs in")
    parser.add_argument(
        "--lerobot-env", help="evaluate in LeRobot's environment of this type (pusht, aloha, libero, metaworld, ...)"
    )
    parser.add_argument("--env-task", help="with --lerobot-env: the task or suite (default: the environment's own)")
    parser.add_argument("--n-envs", type=COUNT, default=1, help="with --lerobot-env: environments stepped in parallel")
    parser.add_argument(
        "--max-episode-steps",
        type=COUNT,
        help="cut every episode here, short of the benchmark's own limit: a quick check of a chain, not a success "
        "rate to report",
    )
    parser.add_argument(
        "--resume",
        action="store_true",
        help=f"continue an interrupted evaluation in --output: the episodes already logged in OUTPUT/{EPISODES} by "
        "the same evaluation are read back, not run again (results as if never interrupted)",
    )
    add_output(
        parser,
        "outputs/eval",
        f"where report.json, report.md and the plots go, and each row's episodes as they finish (OUTPUT/{EPISODES})",
    )


def run(args: argparse.Namespace) -> int:
    if args.lerobot_env:
        return _eval_in_lerobot_env(args)
    # every registered benchmark is checked again below once the policies name theirs; a typo is caught here first
    tasks(args.env or DEFAULT_BENCHMARK, args.tasks)
    modes = dict(_policy_modes(entry, args.modes) for entry in args.policy)
    rtc = _real_time_chunking(args, modes)
    check_writable(args.output)
    from snapflow.evaluation.pipeline import evaluate, labelled_runs, trained_benchmark
    from snapflow.evaluation.report import markdown_report, write_report
    from snapflow.inference.fast_paths import apply_fast_path
    from snapflow.sources import open_policy

    opened = {path: open_policy(path) for path in modes}
    # a bare 'teacher' at each policy's own steps, named by them (teacher-4 for GR00T N1.7)
    policies = {path: (opened[path], [opened[path].resolve_mode(mode) for mode in modes[path]]) for path in modes}
    if args.fast_path:
        for policy, _ in policies.values():
            apply_fast_path(policy.policy, args.fast_path)
    first, _ = next(iter(policies.values()))
    env = args.env or trained_benchmark(first)
    report = evaluate(
        labelled_runs(policies),
        make_benchmark(env),
        tasks(env, args.tasks),
        args.episodes,
        data=args.data,
        progress=not args.no_progress,
        episode_logs=Path(args.output) / EPISODES,
        resume=args.resume,
        first_variation=args.first_variation,
        max_episode_steps=args.max_episode_steps,
        rtc=rtc,
        **given({"n_act": args.n_act, "seed": args.seed}),
    )
    write_report(report, args.output)
    print(markdown_report(report))
    print(f"wrote report.json, report.md and PNG plots to {args.output}")
    return 0


def _interrupted(args: argparse.Namespace) -> str:
    if args.lerobot_env:
        return nothing_written(args)
    return (
        f"interrupted; the episodes finished so far are kept in {Path(args.output) / EPISODES}: run the same command "
        "with --resume to continue"
    )


def _real_time_chunking(args: argparse.Namespace, modes: dict[str, list[SamplingMode]]) -> RealTimeChunking | None:
    """The real-time chunking setting of --inference-delay, --rtc and --execution-horizon, checked against every
    mode and --n-act before anything loads (the chunk length is checked once the policies are open)."""
    if args.inference_delay is None:
        extra = [
            flag for flag, value in (("--rtc", args.rtc), ("--execution-horizon", args.execution_horizon)) if value
        ]
        if extra:
            raise InvalidInputError(f"{' and '.join(extra)} set how chunks continue under --inference-delay: give it")
        return None
    rtc = RealTimeChunking(args.inference_delay, args.rtc or "auto", args.execution_horizon)
    for path_modes in modes.values():
        for mode in path_modes:
            rtc.for_mode(mode)
    n_act = args.n_act or N_ACT
    if rtc.delay > n_act:
        raise InvalidInputError(
            f"--inference-delay {rtc.delay} is more than the {n_act} actions a chunk runs (--n-act): a chunk is "
            "planned while the previous one's last D actions run"
        )
    return rtc


def _policy_modes(entry: str, default: list[SamplingMode]) -> tuple[str, list[SamplingMode]]:
    """``PATH`` (the --modes) or ``PATH=MODES``: the sampling modes of one policy of several."""
    path, separator, modes = entry.rpartition("=")
    if not separator:
        return entry, default
    return path, [SamplingMode.parse(name) for name in modes.split(",")]


def _eval_in_lerobot_env(args: argparse.Namespace) -> int:
    if len(args.policy) != 1:
        raise InvalidInputError("--lerobot-env evaluates one distilled LeRobot policy directory at a time")
    if args.resume:
        raise InvalidInputError("--resume continues snapflow's own evaluator; a --lerobot-env evaluation runs whole")
    if args.inference_delay is not None:
        raise InvalidInputError(
            "--inference-delay runs snapflow's own evaluator; in LeRobot's environment a policy's real-time chunking "
            "is its config's (rtc_config)"
        )
    if args.first_variation:
        raise InvalidInputError(
            "--first-variation chooses the variations of snapflow's own evaluator; in LeRobot's environment, "
            "episode k starts from the environment's own initial state k"
        )
    check_writable(args.output)
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
        fast_path=args.fast_path,
        **given({"seed": args.seed}),
    )
    write_lerobot_eval(report, args.output)
    print(lerobot_eval_table(report))
    print(f"wrote report.json, report.md and each mode's eval_info.json to {args.output}")
    return 0
