"""What a new user meets, through the CLI as a user runs it: a fresh interpreter per command. Each refusal is one line
on stderr and exit code 2, arrives before anything heavy loads where the arguments alone decide it, and writes
nothing to the output; Ctrl-C says what was kept."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import pytest

import snapflow

UNWRITABLE = "/sys/snapflow-test-output"  # sysfs refuses new files even to root: a real unwritable folder


def _snapflow(
    *arguments: str, cwd: Path | None = None, missing: tuple[str, ...] = (), planted: str = ""
) -> subprocess.CompletedProcess:
    """``snapflow ARGUMENTS`` in a new interpreter; ``missing`` modules cannot be imported there, as if their extra
    were not installed; ``planted`` code runs first (a bug planted in the library)."""
    code = "".join(f"sys.modules[{module!r}] = None\n" for module in missing)
    script = f"import sys\n{code}{planted}from snapflow.cli import main\nsys.exit(main(sys.argv[1:]))\n"
    return subprocess.run(
        [sys.executable, "-c", script, *arguments], capture_output=True, text=True, cwd=cwd, timeout=600
    )


def _assert_refused(result: subprocess.CompletedProcess, *words: str) -> str:
    lines = result.stderr.strip().splitlines()
    assert result.returncode == 2, result.stderr
    assert len(lines) == 1 and "Traceback" not in result.stderr, result.stderr
    for word in words:
        assert word in lines[0], lines[0]
    return lines[0]


ARGUMENT_MISTAKES = {
    "zero episodes": (["collect", "--episodes", "0"], "--episodes", "at least 1"),
    "negative collection noise": (["collect", "--action-noise", "-0.1"], "--action-noise", "at least 0"),
    "zero actions per chunk": (["eval", "--policy", "run", "--n-act", "0"], "--n-act", "at least 1"),
    "negative episodes": (["eval", "--policy", "run", "--episodes", "-3"], "--episodes"),
    "zero steps": (["train", "--data", "d", "--steps", "0"], "--steps", "at least 1"),
    "zero checkpoint interval": (["train", "--data", "d", "--checkpoint-every", "0"], "--checkpoint-every"),
    "validation share above 1": (["train", "--data", "d", "--val-fraction", "1.5"], "--val-fraction", "at most 1"),
    "nothing left to train on": (["train", "--data", "d", "--val-fraction", "1"], "--val-fraction", "below 1"),
    "an average that never moves": (
        ["distill", "--teacher", "t", "--data", "d", "--ema-decay", "1"],
        "--ema-decay",
        "below 1",
    ),
    "no teacher steps": (["toy", "--teacher-steps", "0"], "--teacher-steps", "at least 1"),
    "negative lambda": (["distill", "--teacher", "t", "--data", "d", "--lambda", "-1"], "--lambda", "at least 0"),
    "alpha above 1": (["distill", "--teacher", "t", "--data", "d", "--alpha", "1.5"], "--alpha", "at most 1"),
    "infinite learning rate": (["train", "--data", "d", "--learning-rate", "inf"], "--learning-rate", "finite"),
    "unknown time distribution": (
        ["train", "--data", "d", "--time-distribution", "gamma:2"],
        "--time-distribution",
        "unknown time distribution 'gamma:2'; choose one of uniform, beta:A, shift:S",
    ),
    "negative beta of the teacher's times": (
        ["train", "--data", "d", "--time-distribution", "beta:-1.5"],
        "--time-distribution",
        "positive",
    ),
    "time distribution of a LeRobot teacher": (
        ["train", "--policy-type", "smolvla", "--dataset", "d", "--time-distribution", "beta:1.5"],
        "--time-distribution: a LeRobot teacher trains on its own type's flow-matching times",
    ),
    "no timed calls": (["bench", "--architecture", "mlp", "--repeats", "0"], "--repeats"),
    "no workers": (["sweep", "config.toml", "--workers", "0"], "--workers"),
    "mistyped mode": (["eval", "--policy", "run", "--modes", "snapflow-x"], "unknown sampling mode 'snapflow-x'"),
    "a real-time chunking kind without a delay": (
        ["eval", "--policy", "run", "--rtc", "inpaint"],
        "--rtc",
        "--inference-delay",
    ),
    "a delay past the actions a chunk runs": (
        ["eval", "--policy", "run", "--inference-delay", "5", "--n-act", "4"],
        "--inference-delay 5",
        "--n-act",
    ),
    "guidance of a jump": (
        ["eval", "--policy", "run", "--inference-delay", "2", "--rtc", "guided", "--modes", "teacher-10,snapflow-1"],
        "steers Euler steps; snapflow-1 jumps",
    ),
    "a negative delay": (["eval", "--policy", "run", "--inference-delay", "-1"], "--inference-delay", "at least 0"),
    "a delay in LeRobot's environment": (
        ["eval", "--policy", "run", "--lerobot-env", "pusht", "--inference-delay", "2"],
        "--inference-delay runs snapflow's own evaluator",
    ),
    "a server open to the network without TLS": (["serve", "--host", "0.0.0.0"], "--host 0.0.0.0", "--tls-cert"),
    "TLS without its client CA": (
        ["serve", "--tls-cert", "c.pem", "--tls-key", "k.pem"],
        "all three of --tls-cert, --tls-key and --tls-client-ca",
    ),
    "resume in LeRobot's environment": (
        ["eval", "--policy", "run", "--lerobot-env", "pusht", "--resume"],
        "--resume continues snapflow's own evaluator",
    ),
    "mistyped task": (["collect", "--tasks", "reach-v9"], "unknown metaworld task(s) ['reach-v9']"),
    "unknown camera": (["collect", "--image-size", "32", "--extra-cameras", "wrist"], "has no camera(s) ['wrist']"),
    "mistyped target": (["toy-compare", "--targets", "euler"], "TARGET:STEPS"),
    "a LeRobot student written for lerobot-train, sharded": (
        ["distill", "--policy", "lerobot/pi05_base", "--lerobot-train", "--shard"],
        "--lerobot-train writes no training run, so it shards none",
    ),
    "objective option without a value": (
        ["distill", "--teacher", "t", "--data", "d", "--objective-option", "adaptive_power"],
        "--objective-option",
        "NAME=VALUE",
    ),
}


@pytest.mark.parametrize("case", ARGUMENT_MISTAKES, ids=list(ARGUMENT_MISTAKES))
def test_argument_mistakes_are_refused_in_one_line_before_torch_loads(tmp_path, case):
    arguments, *words = ARGUMENT_MISTAKES[case]
    output = tmp_path / "out"
    if arguments[0] not in ("sweep", "serve"):  # the two commands that write no output folder
        arguments = [*arguments, "--output", str(output)]
    probe = tmp_path / "modules.txt"
    script = (
        "import sys\nfrom snapflow.cli import main\n"
        "try:\n    code = main(sys.argv[2:])\nexcept SystemExit as exit_:\n    code = exit_.code\n"
        "open(sys.argv[1], 'w').write(' '.join(m for m in ('torch', 'metaworld', 'mujoco') if m in sys.modules))\n"
        "sys.exit(code)\n"
    )
    result = subprocess.run(
        [sys.executable, "-c", script, str(probe), *arguments], capture_output=True, text=True, timeout=120
    )
    _assert_refused(result, *words)
    assert probe.read_text() == "", f"loaded before refusing: {probe.read_text()}"
    assert not output.exists()


def test_help_and_version_load_no_torch_and_every_option_says_what_it_does():
    from snapflow.cli import build_parser, command_parsers

    for name, command in command_parsers(build_parser()).items():
        for action in command._actions:
            assert action.help, f"snapflow {name} {'/'.join(action.option_strings) or action.dest} has no help"
        # one name for where a command writes (the sweep writes where its config says; serve writes nothing; the
        # checkpoint archive writes where its manifest says)
        outputs = [action.option_strings for action in command._actions if action.dest == "output"]
        assert outputs == ([] if name in ("sweep", "serve", "checkpoints") else [["--output", "--output-dir"]]), name
    script = "import sys\nfrom snapflow.cli import main\ntry:\n    main(sys.argv[1:])\nexcept SystemExit:\n    pass\nprint('torch' in sys.modules)\n"
    for arguments in (["--help"], ["train", "--help"], ["--version"]):
        result = subprocess.run([sys.executable, "-c", script, *arguments], capture_output=True, text=True)
        assert result.stdout.strip().endswith("False"), (arguments, result.stdout)
    version = subprocess.run([sys.executable, "-m", "snapflow.cli", "--version"], capture_output=True, text=True)
    assert version.stdout.strip() == f"snapflow {snapflow.__version__}"
    assert "(default: 5000)" in subprocess.run(
        [sys.executable, "-m", "snapflow.cli", "train", "--help"], capture_output=True, text=True
    ).stdout.replace("\n", " ")


MISSING_EXTRAS = {
    "bench pi0.5 without lerobot": (["bench", "--architecture", "pi05"], "lerobot"),
    "distill LeRobot without lerobot": (
        ["distill", "--policy", "lerobot/smolvla_base", "--dataset", "lerobot/pusht"],
        "lerobot",
    ),
    "eval in LeRobot's env without lerobot": (["eval", "--policy", "run", "--lerobot-env", "pusht"], "lerobot"),
    "collect without metaworld": (["collect", "--episodes", "1", "--tasks", "reach-v3"], "metaworld"),
}


@pytest.mark.parametrize("case", MISSING_EXTRAS, ids=list(MISSING_EXTRAS))
def test_a_missing_extra_is_named_with_its_install_command(tmp_path, case):
    arguments, module = MISSING_EXTRAS[case]
    output = tmp_path / "out"
    result = _snapflow(*arguments, "--output", str(output), "--no-progress", cwd=tmp_path, missing=(module,))
    _assert_refused(result, f'pip install "snapflow-vla[{module}]"')
    assert not output.exists()


def test_a_planted_bug_shows_its_traceback_and_where_to_report_it_not_a_one_line_refusal(tmp_path):
    """A ValueError from snapflow's own code, not from the user's input, is a bug: its traceback, then a line saying
    so and where to report it, exit code 1 (a user's mistake is a named error: one line, exit code 2)."""
    planted = (
        "import snapflow.benchmark.bench as bench\n"
        "def broken(*arguments, **options):\n"
        "    raise ValueError('planted: an invariant of the library broke')\n"
        "bench.run_bench = broken\n"
    )
    arguments = ["bench", "--architecture", "mlp", "--no-progress", "--output", str(tmp_path / "out")]
    result = _snapflow(*arguments, cwd=tmp_path, planted=planted)
    assert result.returncode == 1, result.stderr
    assert "Traceback (most recent call last)" in result.stderr and "in broken" in result.stderr
    assert "ValueError: planted: an invariant of the library broke" in result.stderr
    last = result.stderr.strip().splitlines()[-1]
    assert last.startswith(f"snapflow bench: this is a bug in snapflow {snapflow.__version__}, not a mistake in your")
    assert "please report it, with the command you ran and the traceback above" in last
    # the same command with the user's mistake instead stays one named line
    _assert_refused(_snapflow("bench", "--architecture", "mlp", "--repeats", "0", cwd=tmp_path), "--repeats")


@pytest.mark.parametrize(
    "arguments",
    [
        ["toy", "--teacher-steps", "1"],
        ["collect", "--tasks", "reach-v3", "--episodes", "1"],
        ["train", "--data", "missing"],
        ["distill", "--teacher", "t", "--data", "d"],
        ["eval", "--policy", "run"],
        ["demo"],
    ],
    ids=lambda arguments: arguments[0],
)
def test_an_output_that_cannot_be_written_is_refused_before_any_work(tmp_path, arguments):
    result = _snapflow(*arguments, "--output", f"{UNWRITABLE}/run", "--no-progress", cwd=tmp_path)
    _assert_refused(result, f"cannot write to {UNWRITABLE}/run", "choose another --output")


def test_a_jump_mode_on_a_teacher_is_refused_not_reported_as_snapflow(teacher_checkpoint, tmp_path):
    output = tmp_path / "out"
    arguments = ["eval", "--policy", str(teacher_checkpoint), "--modes", "teacher-10,snapflow-1", "--tasks", "reach-v3"]
    result = _snapflow(*arguments, "--episodes", "1", "--output", str(output), "--no-progress")
    _assert_refused(
        result, "is not SnapFlow-distilled (a flow-matching teacher)", "use teacher-N or naive, or distill it first"
    )
    assert not output.exists()


@pytest.mark.parametrize("given", ["run", "run/checkpoints/step_0000004"])
def test_a_lerobot_training_checkpoint_given_as_a_policy_is_refused_naming_the_folder_to_pass(tmp_path, given):
    """What `snapflow train` / `distill` leave of a LeRobot policy: checkpoints that resume training, and beside them
    the policy folder the run exported, which is what opens."""
    checkpoint = tmp_path / "run" / "checkpoints" / "step_0000004"
    checkpoint.mkdir(parents=True)
    (checkpoint / "policy.json").write_text(json.dumps({"format": "snapflow-lerobot-run", "policy": "smolvla"}))
    (tmp_path / "run" / "latest.json").write_text(json.dumps({"checkpoint": "checkpoints/step_0000004"}))
    (tmp_path / "run" / "lerobot_policy").mkdir()
    (tmp_path / "run" / "lerobot_policy" / "config.json").write_text("{}")
    result = _snapflow("eval", "--policy", given, "--output", str(tmp_path / "out"), "--no-progress", cwd=tmp_path)
    _assert_refused(result, "training checkpoint of a LeRobot policy", "pass its policy folder run/lerobot_policy")


def test_a_second_demo_in_the_same_folder_is_refused_at_once_with_the_flag_that_exists(tmp_path):
    (tmp_path / "demo" / "data").mkdir(parents=True)
    result = _snapflow("demo", "--output", str(tmp_path / "demo"), "--no-progress")
    _assert_refused(result, "holds a demo run", "--resume", "--output")
    assert [path.name for path in (tmp_path / "demo").iterdir()] == ["data"]


def _start_interruptible(command: list[str]) -> subprocess.Popen:
    """Start ``command`` as a foreground job would run: a shell that starts a job in the
    background (as CI may run this suite) has it ignore SIGINT, and children inherit that."""
    return subprocess.Popen(
        command, stderr=subprocess.PIPE, text=True, preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL)
    )


def _interrupt_when(process: subprocess.Popen, ready: Callable[[], bool]) -> str:
    """SIGINT ``process`` (Ctrl-C) once ``ready()``; its last stderr line."""
    deadline = time.monotonic() + 300
    while not ready():
        assert process.poll() is None and time.monotonic() < deadline, process.communicate()
        time.sleep(0.05)
    process.send_signal(signal.SIGINT)
    _, stderr = process.communicate(timeout=120)
    assert process.returncode == -signal.SIGINT, stderr  # ended by the signal, once the message was out
    return stderr.strip().splitlines()[-1]


@pytest.mark.slow
def test_ctrl_c_says_what_was_kept(tmp_path):
    from tests.training.fixtures import synthetic_demonstrations

    data = synthetic_demonstrations().save(tmp_path / "data")
    train = [
        sys.executable,
        "-m",
        "snapflow.cli",
        "train",
        "--policy-type",
        "mlp",
        "--data",
        str(data),
        "--no-progress",
    ]
    run = tmp_path / "early"
    process = _start_interruptible([*train, "--output", str(run)])
    line = _interrupt_when(process, lambda: (run / ".snapflow.lock").exists())
    assert "before the first checkpoint" in line and "--resume" not in line, line

    run = tmp_path / "late"
    process = _start_interruptible([*train, "--output", str(run), "--checkpoint-every", "1"])
    line = _interrupt_when(process, lambda: (run / "latest.json").exists())
    assert "keeps its last checkpoint" in line and "--resume" in line, line

    output = tmp_path / "demonstrations"
    collect = [sys.executable, "-m", "snapflow.cli", "collect", "--tasks", "reach-v3", "--output", str(output)]
    process = _start_interruptible([*collect, "--no-progress"])
    line = _interrupt_when(process, lambda: (output / ".snapflow.lock").exists())
    assert "each task finished so far is kept in" in line and "the same command collects the others" in line, line
    assert not (output / "meta.json").exists()
