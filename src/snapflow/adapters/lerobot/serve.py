"""A SnapFlow student behind LeRobot's async inference: LeRobot's own ``PolicyServer`` and gRPC service, in a process
where snapflow's student types are registered (this module imports them) and in the server's list of supported types,
so LeRobot's robot client, unchanged, asks for ``policy_type=snapflow_<type>``. Messages are read through
:mod:`.safe_pickle`'s allow-list: LeRobot's own server unpickles whatever a client sends, running its code.

LeRobot's server alone refuses the student's type (its supported list is fixed), and never imports third-party
plugins; asked for the teacher's type (``smolvla``) with a student folder, it would load the folder as a plain
SmolVLA, drop phi_s with an "unexpected keys" warning and run ten denoising passes a chunk. This server refuses that
request by name instead.

Where LeRobot's server loads the folder a client names as it is (a SmolVLM kept inside the folder is then read from
the server's working directory, so it served only when started inside the folder), this one loads it as snapflow
does, from any working directory. A request it cannot serve (a student never distilled, a type it does not serve, a
folder that does not open) fails ``SendPolicyInstructions`` with a gRPC status that carries the reason, and a chunk
that fails fails ``GetActions`` so: LeRobot's server logs both and answers with nothing. It binds its port alone
(gRPC would share it with another server through SO_REUSEPORT), and LeRobot's server log goes to a folder of its own
(:func:`log_directory`), never into the working directory, which may be a policy folder.
"""

from __future__ import annotations

import importlib
import os
import pickle
import threading
from collections.abc import Callable, Iterator
from concurrent import futures
from contextlib import contextmanager
from pathlib import Path
from types import ModuleType, SimpleNamespace
from typing import Any

import grpc
from lerobot.async_inference import constants
from lerobot.async_inference.configs import PolicyServerConfig
from lerobot.transport import services_pb2, services_pb2_grpc

import snapflow.adapters.lerobot.plugin  # noqa: F401 - registers the student types with LeRobot in this process
from snapflow.adapters.lerobot import safe_pickle
from snapflow.adapters.lerobot.checkpoint import load_pretrained_policy
from snapflow.adapters.lerobot.local_vlm import saved_processors
from snapflow.adapters.lerobot.plugin.modeling_snapflow import NotDistilledError, SnapFlowStudent
from snapflow.adapters.lerobot.student_folder import refuse_student_as_teacher
from snapflow.adapters.lerobot_types import LEROBOT_POLICY_TYPES
from snapflow.errors import InvalidInputError


def log_directory() -> Path:
    """Where LeRobot's server writes its log (``logs/policy_server_<time>.log`` inside): ``$SNAPFLOW_SERVE_LOGS``, or
    ``~/.cache/snapflow/serve``."""
    return Path(os.environ.get("SNAPFLOW_SERVE_LOGS", Path.home() / ".cache" / "snapflow" / "serve")).expanduser()


@contextmanager
def _in_directory(path: Path) -> Iterator[None]:
    """The working directory ``path`` (made if missing) while the block runs."""
    path.mkdir(parents=True, exist_ok=True)
    before = Path.cwd()
    os.chdir(path)
    try:
        yield
    finally:
        os.chdir(before)


def _lerobot_server_module() -> ModuleType:
    """LeRobot's policy server module, imported where its log goes: it opens its log file at import, under logs/ of
    the working directory."""
    with _in_directory(log_directory()):
        return importlib.import_module("lerobot.async_inference.policy_server")


lerobot_policy_server = _lerobot_server_module()
# LeRobot's server reads each message with its module's ``pickle.loads``: here that name reads through the protocol's
# allow-list, so an observation that names any other callable is refused before it runs (what it sends back is ours)
lerobot_policy_server.pickle = SimpleNamespace(loads=safe_pickle.loads, dumps=pickle.dumps)


class PortInUseError(InvalidInputError):
    """The address a server was asked to listen on is taken."""


def refusal_status(error: BaseException) -> grpc.StatusCode | None:
    """The gRPC status that tells a client why its request cannot be served; None for a bug (its traceback is the
    server's to log)."""
    if isinstance(error, NotDistilledError):
        return grpc.StatusCode.FAILED_PRECONDITION
    if isinstance(error, FileNotFoundError):
        return grpc.StatusCode.NOT_FOUND
    if isinstance(error, (ValueError, OSError)):  # snapflow's refusals are ValueErrors, as are LeRobot's
        return grpc.StatusCode.INVALID_ARGUMENT
    return None


class StudentPolicyServer(lerobot_policy_server.PolicyServer):
    """LeRobot's policy server, reading no client's code, loading a folder from any working directory, and telling
    the client why it refuses (:func:`refusal_status`)."""

    def __init__(self, config: PolicyServerConfig) -> None:
        super().__init__(config)
        self._call = threading.local()  # what failed in the chunk of the GetActions call this thread answers

    def SendPolicyInstructions(self, request: Any, context: Any) -> Any:  # noqa: N802 - gRPC's method name
        if not self.running:  # LeRobot's server ignores instructions before Ready, and so reads nothing then
            return super().SendPolicyInstructions(request, context)
        specs = self._read(context, lambda: safe_pickle.loads(request.data))
        try:
            self._load(specs)
        except Exception as error:
            self._refuse(context, error, "cannot serve " + str(getattr(specs, "pretrained_name_or_path", "")))
        return services_pb2.Empty()

    def _load(self, specs: Any) -> None:
        """What LeRobot's ``SendPolicyInstructions`` does with the client's ``specs``, with the folder loaded as
        snapflow loads it (its kept VLM found wherever the server runs) and a student that cannot sample refused."""
        source, policy_type = str(specs.pretrained_name_or_path), specs.policy_type
        refuse_student_as_teacher(source, policy_type)  # by name, before "not served" (X-VLA's type is not)
        if policy_type not in constants.SUPPORTED_POLICIES:
            raise InvalidInputError(
                f"policy type {policy_type!r} is not served; served: {constants.SUPPORTED_POLICIES}"
            )
        policy = load_pretrained_policy(source)
        if policy.config.type != policy_type:
            raise InvalidInputError(f"{source} holds a {policy.config.type!r} policy, not a {policy_type!r} one")
        if isinstance(policy, SnapFlowStudent):
            policy.requested_sampling_mode()  # a student never distilled has no jump: refused now, not every chunk
        self.logger.info(f"loading {policy_type} from {source} for {specs.device}")
        device = {"device": specs.device}
        self.preprocessor, self.postprocessor = saved_processors(
            policy.config,
            source,
            specs.device,
            {"rename_observations_processor": {"rename_map": specs.rename_map}},
            postprocessor_overrides={"device_processor": device},
        )
        self.device, self.policy_type = specs.device, policy_type
        self.lerobot_features, self.actions_per_chunk = specs.lerobot_features, specs.actions_per_chunk
        self.policy = policy.to(specs.device)

    def SendObservations(self, request_iterator: Any, context: Any) -> Any:  # noqa: N802 - gRPC's method name
        return self._read(context, lambda: super(StudentPolicyServer, self).SendObservations(request_iterator, context))

    def GetActions(self, request: Any, context: Any) -> Any:  # noqa: N802 - gRPC's method name
        self._call.failure = None
        answer = super().GetActions(request, context)  # LeRobot's logs a failed chunk and answers with nothing
        if self._call.failure is not None:
            self._refuse(context, self._call.failure, "no chunk", grpc.StatusCode.INTERNAL)
        return answer

    def _predict_action_chunk(self, observation: Any) -> Any:
        try:
            return super()._predict_action_chunk(observation)
        except Exception as error:
            self._call.failure = error
            raise

    def _refuse(self, context: Any, error: Exception, what: str, other: grpc.StatusCode | None = None) -> None:
        """Answer the client with the status :func:`refusal_status` gives ``error`` (``other`` for any other error;
        without one, a bug is raised as it is)."""
        status = refusal_status(error) or other
        if status is None:
            raise error
        self.logger.error(f"{what}: {type(error).__name__}: {error}")
        context.abort(status, f"{what}: {error}")

    def _read(self, context: Any, read: Any) -> Any:
        """``read()``; a refused payload is logged by name and answered INVALID_ARGUMENT, and serving goes on."""
        try:
            return read()
        except safe_pickle.RefusedPayload as refused:
            self.logger.error(f"client {context.peer()}: {refused}")
            context.abort(grpc.StatusCode.INVALID_ARGUMENT, str(refused))


def tls_credentials(certificate: Path, key: Path, client_ca: Path) -> grpc.ServerCredentials:
    """gRPC's TLS credentials of a server that proves itself with ``certificate`` / ``key`` and serves only clients
    whose own certificate ``client_ca`` signed (mutual TLS: the clients are authenticated, and everything is
    encrypted)."""
    files = {"--tls-cert": certificate, "--tls-key": key, "--tls-client-ca": client_ca}
    missing = [f"{flag} {path}" for flag, path in files.items() if not Path(path).is_file()]
    if missing:
        raise InvalidInputError(f"no such file: {', '.join(missing)}")
    return grpc.ssl_server_credentials(
        [(Path(key).read_bytes(), Path(certificate).read_bytes())],
        root_certificates=Path(client_ca).read_bytes(),
        require_client_auth=True,
    )


def start_server(
    config: PolicyServerConfig, credentials: grpc.ServerCredentials | None = None
) -> tuple[grpc.Server, StudentPolicyServer]:
    """LeRobot's policy server on ``config.host:config.port``, started, with snapflow's student types supported,
    over TLS where ``credentials`` are given (:func:`tls_credentials`); the gRPC server and the policy server it
    serves (as LeRobot's ``serve`` builds them)."""
    for declared in LEROBOT_POLICY_TYPES.values():  # registered by the plugin import; now also supported
        if declared.student_type not in constants.SUPPORTED_POLICIES:
            constants.SUPPORTED_POLICIES.append(declared.student_type)  # the list LeRobot's server checks
    policy_server = StudentPolicyServer(config)
    # gRPC turns SO_REUSEPORT on by default: a second server on the port would listen beside the first, each taking
    # some of its clients
    server = grpc.server(futures.ThreadPoolExecutor(max_workers=4), options=[("grpc.so_reuseport", 0)])
    services_pb2_grpc.add_AsyncInferenceServicer_to_server(policy_server, server)
    address = f"{config.host}:{config.port}"
    try:
        if credentials is None:
            server.add_insecure_port(address)
        else:
            server.add_secure_port(address, credentials)
    except RuntimeError:  # gRPC's "Failed to bind to address"
        raise PortInUseError(
            f"cannot listen on {address}: the port is in use (another server?) or the address is not this "
            "machine's; choose another --port"
        ) from None
    server.start()
    return server, policy_server


def serve(
    config: PolicyServerConfig,
    credentials: grpc.ServerCredentials | None = None,
    ready: Callable[[], None] | None = None,
) -> None:
    """Serve until interrupted (over TLS where ``credentials`` are given); ``ready`` is called once the server
    listens (a port already in use is refused before: :class:`PortInUseError`)."""
    server, policy_server = start_server(config, credentials)
    if ready is not None:
        ready()
    policy_server.logger.info(
        f"snapflow: LeRobot's PolicyServer serving SnapFlow students on {config.host}:{config.port}"
    )
    server.wait_for_termination()


__all__ = [
    "PortInUseError",
    "StudentPolicyServer",
    "log_directory",
    "refusal_status",
    "tls_credentials",
    "start_server",
    "serve",
]
