"""A SnapFlow student behind LeRobot's async inference: LeRobot's own ``PolicyServer`` and gRPC service, in a process
where snapflow's student types are registered (this module imports them) and in the server's list of supported types,
so LeRobot's robot client, unchanged, asks for ``policy_type=snapflow_<type>``. Messages are read through
:mod:`.safe_pickle`'s allow-list: LeRobot's own server unpickles whatever a client sends, running its code.

LeRobot's server alone refuses the student's type (its supported list is fixed), and never imports third-party
plugins; asked for the teacher's type (``smolvla``) with a student folder, it would load the folder as a plain
SmolVLA, drop phi_s with an "unexpected keys" warning and run ten denoising passes a chunk. This server refuses that
request by name instead.
"""

from __future__ import annotations

import pickle
from concurrent import futures
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import grpc
from lerobot.async_inference import constants
from lerobot.async_inference import policy_server as lerobot_policy_server
from lerobot.async_inference.configs import PolicyServerConfig
from lerobot.async_inference.policy_server import PolicyServer
from lerobot.transport import services_pb2_grpc

import snapflow.adapters.lerobot.plugin  # noqa: F401 - registers the student types with LeRobot in this process
from snapflow.adapters.lerobot import safe_pickle
from snapflow.adapters.lerobot.student_folder import refuse_student_as_teacher
from snapflow.adapters.lerobot_types import LEROBOT_POLICY_TYPES
from snapflow.errors import InvalidInputError

# LeRobot's server reads each message with its module's ``pickle.loads``: here that name reads through the protocol's
# allow-list, so an observation that names any other callable is refused before it runs (what it sends back is ours)
lerobot_policy_server.pickle = SimpleNamespace(loads=safe_pickle.loads, dumps=pickle.dumps)


class StudentPolicyServer(PolicyServer):
    """LeRobot's policy server, reading no client's code and refusing a student asked for under its teacher's type."""

    def SendPolicyInstructions(self, request: Any, context: Any) -> Any:  # noqa: N802 - gRPC's method name
        if self.running:  # LeRobot's server ignores instructions before Ready, and so reads nothing then
            specs = self._read(context, lambda: safe_pickle.loads(request.data))
            refuse_student_as_teacher(specs.pretrained_name_or_path, specs.policy_type)
        return super().SendPolicyInstructions(request, context)

    def SendObservations(self, request_iterator: Any, context: Any) -> Any:  # noqa: N802 - gRPC's method name
        return self._read(context, lambda: super(StudentPolicyServer, self).SendObservations(request_iterator, context))

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
    server = grpc.server(futures.ThreadPoolExecutor(max_workers=4))
    services_pb2_grpc.add_AsyncInferenceServicer_to_server(policy_server, server)
    address = f"{config.host}:{config.port}"
    if credentials is None:
        server.add_insecure_port(address)
    else:
        server.add_secure_port(address, credentials)
    server.start()
    return server, policy_server


def serve(config: PolicyServerConfig, credentials: grpc.ServerCredentials | None = None) -> None:
    """Serve until interrupted (over TLS where ``credentials`` are given)."""
    server, policy_server = start_server(config, credentials)
    policy_server.logger.info(
        f"snapflow: LeRobot's PolicyServer serving SnapFlow students on {config.host}:{config.port}"
    )
    server.wait_for_termination()


__all__ = ["StudentPolicyServer", "tls_credentials", "start_server", "serve"]
