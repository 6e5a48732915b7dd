"""Where ``--policy`` / ``--dataset`` point, and every way a hub repo fails, each told apart in one line.

The CLI runs in a subprocess whose ``HF_ENDPOINT`` (read by huggingface_hub at import) is a tiny HTTP server in
this test that answers as the hub does, or a closed port: nothing leaves the machine, and the session's sealed
Hugging Face cache (``HF_HUB_OFFLINE``, see conftest) is replaced by a fresh one per test.
"""

from __future__ import annotations

import importlib.util
import json
import os
import socket
import subprocess
import sys
import threading
from collections.abc import Iterator
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

import pytest

from snapflow.adapters.hub import HubError, local_folder

# the hub is asked from LeRobot's loaders: without LeRobot, bench and distill stop before it
NEEDS_LEROBOT = pytest.mark.skipif(
    importlib.util.find_spec("lerobot") is None, reason="LeRobot is installed by the README's test command"
)

CONFIG = json.dumps({"type": "smolvla"}).encode()
COMMIT = "0123456789abcdef0123456789abcdef01234567"
# repo name -> (status, headers) as the hub answers for a file of that repo (404s carry the hub's X-Error-Code)
ANSWERS: dict[str, tuple[int, dict[str, str]]] = {
    "missing": (404, {"X-Error-Code": "RepoNotFound"}),
    "gated": (401, {"X-Error-Code": "GatedRepo"}),
    "bad-token": (401, {"X-Error-Message": "Invalid credentials in Authorization header"}),
    "no-rights": (403, {}),
    "not-a-policy": (404, {"X-Error-Code": "EntryNotFound", "X-Repo-Commit": COMMIT}),
    "down": (503, {}),
}


class FakeHub(BaseHTTPRequestHandler):
    """``/[datasets/]owner/<name>/resolve/main/<file>``: the answer ``ANSWERS`` gives ``name``, else the file."""

    requests: list[str] = []  # the repo files asked for (huggingface_hub 1.x also calls /api/ endpoints of its own)

    def do_HEAD(self) -> None:
        self._answer(body=False)

    def do_GET(self) -> None:
        self._answer(body=True)

    def _answer(self, body: bool) -> None:
        if "/resolve/" in self.path:
            FakeHub.requests.append(self.path)
        parts = self.path.removeprefix("/datasets").split("/")
        status, headers = ANSWERS.get(parts[2], (200, {"X-Repo-Commit": COMMIT, "ETag": '"config"'}))
        self.send_response(status)
        for key, value in headers.items():
            self.send_header(key, value)
        content = CONFIG if status == 200 else b""
        self.send_header("Content-Length", str(len(content)))
        self.end_headers()
        if body:
            self.wfile.write(content)

    def log_message(self, *args: object) -> None:  # quiet test output
        pass


@pytest.fixture(scope="module")
def hub() -> Iterator[str]:
    server = ThreadingHTTPServer(("127.0.0.1", 0), FakeHub)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    yield f"http://127.0.0.1:{server.server_address[1]}"
    server.shutdown()


@pytest.fixture
def hanging_up_hub() -> Iterator[tuple[str, list[str]]]:
    """An endpoint that reads each request's first line and closes the connection unanswered (a hub that cannot be
    reached), and the paths asked for: huggingface_hub 0.x retries an unreachable hub for ~25 s per file, so a path
    asked for twice is a retry (huggingface_hub 1.x also asks once a process for its agent registry)."""
    listener = socket.create_server(("127.0.0.1", 0))
    paths: list[str] = []

    def hang_up() -> None:
        while True:
            try:
                connection, _ = listener.accept()
            except OSError:  # closed at the end of the test
                return
            with connection, connection.makefile("rb") as request:
                paths.append(request.readline().decode().split(" ")[1])

    threading.Thread(target=hang_up, daemon=True).start()
    yield f"http://127.0.0.1:{listener.getsockname()[1]}", paths
    listener.close()


def _environment(endpoint: str, cwd: Path, **env: str) -> dict[str, str]:
    """This process's environment with the hub at ``endpoint``, online, and fresh caches under ``cwd``."""
    sealed = ("HF_HUB_OFFLINE", "TRANSFORMERS_OFFLINE", "HF_HUB_CACHE", "HF_TOKEN", "HF_HUB_ETAG_TIMEOUT")
    environment = {key: value for key, value in os.environ.items() if key not in sealed}
    return {
        **environment,
        "HF_ENDPOINT": endpoint,
        "HF_HOME": str(cwd / "hf_home"),
        "HF_LEROBOT_HOME": str(cwd / "lerobot_home"),
        **env,
    }


def _run(arguments: list[str], endpoint: str, cwd: Path, **env: str) -> tuple[int, list[str]]:
    """``python -m snapflow.cli`` against ``endpoint`` with a fresh HF cache: exit code and stderr lines."""
    done = subprocess.run(
        [sys.executable, "-m", "snapflow.cli", *arguments],
        cwd=cwd,
        env=_environment(endpoint, cwd, **env),
        capture_output=True,
        text=True,
        timeout=120,
    )
    return done.returncode, done.stderr.splitlines()


def _bench(policy: str) -> list[str]:
    return ["bench", "--policy", policy, "--repeats", "1", "--warmup", "0", "--output", "bench"]


def _assert_one_line(result: tuple[int, list[str]], command: str, *phrases: str) -> None:
    code, lines = result
    assert code == 2 and len(lines) == 1, lines
    assert lines[0].startswith(f"snapflow {command}: error: ") and "Traceback" not in lines[0]
    for phrase in phrases:
        assert phrase in lines[0], lines[0]


@NEEDS_LEROBOT
@pytest.mark.parametrize(
    "repo, phrases",
    [
        ("acme/missing", ["no model acme/missing on the Hugging Face Hub", "check the id", "HF_TOKEN"]),
        ("acme/gated", ["acme/gated needs authorisation", "hf auth login", "HF_TOKEN", "/acme/gated"]),
        ("acme/not-a-policy", ["acme/not-a-policy has no config.json: not a LeRobot policy"]),
    ],
)
def test_bench_names_what_is_wrong_with_a_hub_policy_in_one_line(hub, tmp_path, repo, phrases):
    FakeHub.requests.clear()
    _assert_one_line(_run(_bench(repo), hub, tmp_path), "bench", *phrases)
    assert not (tmp_path / "bench").exists()
    assert FakeHub.requests and len(FakeHub.requests) == len(set(FakeHub.requests)), "no file is asked for twice"


@NEEDS_LEROBOT
def test_an_unreachable_hub_is_named_at_once_not_retried(hanging_up_hub, tmp_path):
    endpoint, paths = hanging_up_hub
    result = _run(_bench("acme/policy"), endpoint, tmp_path)
    _assert_one_line(
        result,
        "bench",
        f"cannot reach the Hugging Face Hub ({endpoint}) to fetch acme/policy",
        "pass a local folder",
        "HF_HUB_OFFLINE=1",
    )
    asked_for_the_policy = [path for path in paths if "acme/policy" in path]
    assert len(asked_for_the_policy) == 1, f"retried: {paths}"


@NEEDS_LEROBOT
def test_distill_names_a_missing_hub_dataset_before_the_policy_loads(hub, tmp_path):
    FakeHub.requests.clear()
    arguments = ["distill", "--policy", "acme/policy", "--dataset", "acme/missing", "--output", "run"]
    _assert_one_line(_run(arguments, hub, tmp_path), "distill", "no dataset acme/missing on the Hugging Face Hub")
    assert FakeHub.requests == ["/datasets/acme/missing/resolve/main/meta/info.json"], "the policy is not fetched"
    assert not (tmp_path / "run").exists(), "nothing is written to the output"


def test_a_mistyped_local_policy_folder_is_named_and_never_looked_up(hub, tmp_path):
    (tmp_path / "runs").mkdir()
    FakeHub.requests.clear()
    result = _run(_bench("runs/teacher"), hub, tmp_path)
    _assert_one_line(result, "bench", "no folder runs/teacher (runs/ exists); hub ids are owner/name")
    assert FakeHub.requests == []


def test_a_mistyped_local_dataset_is_named_before_any_loading(hub, tmp_path):
    FakeHub.requests.clear()
    arguments = ["distill", "--policy", "acme/policy", "--dataset", "./data/pusht", "--output", "run"]
    _assert_one_line(_run(arguments, hub, tmp_path), "distill", "no folder ./data/pusht; hub ids are owner/name")
    assert FakeHub.requests == []
    assert not (tmp_path / "run").exists()


FETCH = """
import sys
from snapflow.adapters.hub import HubError, fetch_hub_file
for repo in sys.argv[1:]:
    try:
        print(repo, "->", fetch_hub_file(repo, "config.json", "a LeRobot policy"))
    except HubError as error:
        print(repo, "->", error)
"""


def _fetch(repos: list[str], endpoint: str, cwd: Path, **env: str) -> dict[str, str]:
    """What :func:`fetch_hub_file` gives for each repo, in one subprocess against ``endpoint``."""
    done = subprocess.run(
        [sys.executable, "-c", FETCH, *repos],
        env=_environment(endpoint, cwd, **env),
        capture_output=True,
        text=True,
        timeout=60,
        check=True,
    )
    assert done.stderr == "", done.stderr  # huggingface_hub's retry warnings stay silent
    return dict(line.split(" -> ", 1) for line in done.stdout.splitlines())


def test_every_hub_answer_maps_to_its_one_line_and_a_fetched_file_serves_offline(hub, tmp_path):
    answers = _fetch(["acme/policy", "acme/bad-token", "acme/no-rights", "acme/down"], hub, tmp_path)
    cached = Path(answers["acme/policy"])
    assert cached.read_bytes() == CONFIG and str(tmp_path / "hf_home") in str(cached)
    for repo in ("acme/bad-token", "acme/no-rights"):
        assert answers[repo].startswith(f"{repo} needs authorisation: log in with `hf auth login` or set HF_TOKEN")
    assert answers["acme/down"].startswith("the Hugging Face Hub answered HTTP 503 for acme/down; try again later")
    # offline: the cached copy serves, a repo never fetched is named with the way out
    offline = _fetch(["acme/policy", "acme/other"], hub, tmp_path, HF_HUB_OFFLINE="1")
    assert Path(offline["acme/policy"]) == cached
    assert offline["acme/other"] == (
        "HF_HUB_OFFLINE is set and acme/other is not in the Hugging Face cache; unset it to download from the hub, "
        "or pass a local folder"
    )


@pytest.mark.parametrize(
    "text, folder",
    [("lerobot/smolvla_base", False), ("HuggingFaceTB/SmolVLM2-500M-Video-Instruct", False), ("here", True)],
)
def test_hub_ids_and_existing_folders_are_told_apart(tmp_path, monkeypatch, text, folder):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "here").mkdir()
    assert local_folder(text) == (Path(text) if folder else None)


@pytest.mark.parametrize(
    "text, message",
    [
        ("teacher", "no folder teacher; hub ids are owner/name"),
        ("runs/teacher", "no folder runs/teacher (runs/ exists); hub ids are owner/name"),
        ("runs/a/b", "no folder runs/a/b (runs/ exists); hub ids are owner/name"),
        ("./acme/x", "no folder ./acme/x; hub ids are owner/name"),
        ("~/acme/x", "no folder ~/acme/x; hub ids are owner/name"),
        ("acme\\x", "no folder acme\\x; hub ids are owner/name"),
        ("acme/x/y", "no folder acme/x/y; hub ids are owner/name"),
        ("acme--co/x", "no folder acme--co/x; hub ids are owner/name"),
    ],
)
def test_what_looks_like_a_local_path_is_never_a_hub_id(tmp_path, monkeypatch, text, message):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "runs").mkdir()
    with pytest.raises(FileNotFoundError) as error:
        local_folder(text)
    assert str(error.value) == message


def test_an_absolute_path_names_its_nearest_existing_folder_and_a_file_is_no_folder(tmp_path):
    (tmp_path / "runs").mkdir()
    with pytest.raises(FileNotFoundError) as error:
        local_folder(str(tmp_path / "runs" / "x" / "y"))
    assert str(error.value) == f"no folder {tmp_path}/runs/x/y ({tmp_path}/runs/ exists); hub ids are owner/name"
    (tmp_path / "config.json").write_text("{}")
    with pytest.raises(ValueError, match="config.json is a file; give the folder that holds it"):
        local_folder(str(tmp_path / "config.json"))


@NEEDS_LEROBOT
def test_bench_checks_smolvlas_vlm_folder_or_hub_id_before_the_build(tmp_path, monkeypatch):
    import torch

    from snapflow.benchmark.subjects import make_subject

    monkeypatch.chdir(tmp_path)
    (tmp_path / "runs").mkdir()
    with pytest.raises(FileNotFoundError, match=r"^no folder runs/vlm \(runs/ exists\); hub ids are owner/name$"):
        make_subject(None, "smolvla", torch.device("cpu"), torch.float32, vlm="runs/vlm")
    with pytest.raises(FileNotFoundError, match=r"^runs has no config.json: not a VLM for SmolVLA$"):
        make_subject(None, "smolvla", torch.device("cpu"), torch.float32, vlm="runs")
    # this session is sealed offline (conftest): a hub id is looked up in the empty cache only
    with pytest.raises(HubError, match="^HF_HUB_OFFLINE is set and acme/vlm is not in the Hugging Face cache"):
        make_subject(None, "smolvla", torch.device("cpu"), torch.float32, vlm="acme/vlm")
