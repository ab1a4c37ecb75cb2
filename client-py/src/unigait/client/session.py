"""Connection to one server and the sessions on it."""

from __future__ import annotations

import queue
import threading
from collections.abc import Sequence
from typing import Any

import grpc
import numpy as np

from unigait.client.closing import ClosesOnExit
from unigait.client.connection import ConnectionOptions, make_channel
from unigait.client.errors import ProtocolError, UnigaitError, call
from unigait.client.proto import pb, pb_grpc
from unigait.client.spec import Spec
from unigait.client.tensors import encode
from unigait.client.types import EvaluateResult, ServerInfo, SessionConfig, StepResult

#: Message-size limit of the channel in both directions (256 MiB): fits the largest batch.
DEFAULT_MAX_MESSAGE_BYTES = 256 * 1024 * 1024


class Client(ClosesOnExit):
    """A channel to one ``unigait`` server.

    Plaintext by default (a server on loopback); TLS for ``https://`` addresses or when
    ``root_certificates`` are given, as a server started with ``--allow-remote --tls-cert
    --tls-key --token-file`` requires, with the ``token`` sent as ``authorization: Bearer
    <token>`` on every call (see :mod:`unigait.client.connection`).

    Args:
        address: ``host:port`` (e.g. ``"127.0.0.1:50051"``), ``https://host:port`` (TLS) or
            ``http://host:port`` (plaintext).
        root_certificates: PEM CA bundle that signed the server's certificate (TLS); None with
            an ``https://`` address: the system roots.
        token: Bearer token of the server (``--token-file`` on its side). Sent over TLS, or in
            plaintext only to a loopback host.
        tls_server_name: Certificate name to verify when it differs from the address's host.
        max_message_bytes: Send and receive limit of the channel.
        connect_timeout_s: Wait this long for the channel to come up (None: do not wait).

    Attributes:
        address: The address as given.
        tls: Whether the channel uses TLS.

    Raises:
        ValueError: Contradicting options, or a token that would cross the network in plaintext.
        UnigaitError: UNAVAILABLE when no server answered within ``connect_timeout_s`` (also
            what a TLS/plaintext mismatch or an untrusted certificate looks like).
    """

    def __init__(
        self,
        address: str,
        *,
        root_certificates: bytes | None = None,
        token: str | None = None,
        tls_server_name: str | None = None,
        max_message_bytes: int = DEFAULT_MAX_MESSAGE_BYTES,
        connect_timeout_s: float | None = 10.0,
    ) -> None:
        self.address = address
        self._connection: ConnectionOptions = {
            "root_certificates": root_certificates,
            "token": token,
            "tls_server_name": tls_server_name,
        }
        self._max_message_bytes = max_message_bytes
        self.channel, self.tls = make_channel(
            address,
            root_certificates=root_certificates,
            token=token,
            tls_server_name=tls_server_name,
            options=[
                ("grpc.max_send_message_length", max_message_bytes),
                ("grpc.max_receive_message_length", max_message_bytes),
            ],
        )
        self.stub = pb_grpc.SimulatorStub(self.channel)
        if connect_timeout_s is not None:
            try:
                grpc.channel_ready_future(self.channel).result(timeout=connect_timeout_s)
            except grpc.FutureTimeoutError:
                self.channel.close()
                hint = (
                    "is its certificate signed by the given CA (root_certificates, --tls-ca) "
                    "and issued for this host name, and does it serve TLS at all?"
                    if self.tls
                    else "if it serves TLS, use https://HOST:PORT or root_certificates (--tls-ca)"
                )
                raise UnigaitError(
                    grpc.StatusCode.UNAVAILABLE,
                    f"no unigait server answered at {address} within {connect_timeout_s} s "
                    f"({'TLS' if self.tls else 'plaintext'}; {hint})",
                ) from None

    def connect_to(self, address: str, *, connect_timeout_s: float | None = 10.0) -> Client:
        """A new client for another server with this one's credentials and limits.

        Args:
            address: The other server (e.g. the replacement of a lost one).
            connect_timeout_s: Wait this long for its channel (None: do not wait).
        """
        return Client(
            address,
            **self._connection,
            max_message_bytes=self._max_message_bytes,
            connect_timeout_s=connect_timeout_s,
        )

    def server_info(self) -> ServerInfo:
        """Server version, protocol version and limits."""
        return ServerInfo.from_proto(
            call(lambda: self.stub.GetServerInfo(pb.GetServerInfoRequest()))
        )

    def create_session(self, config: SessionConfig) -> Session:
        """Create a session, reset it and return it (its first observations in ``initial``)."""
        req = pb.CreateSessionRequest(config=config.to_proto())
        resp = call(lambda: self.stub.CreateSession(req))
        spec = Spec.from_proto(resp.spec)
        session = Session(self, resp.session_id, spec, StepResult.from_proto(resp.initial, spec))
        if config.terrain_columns and spec.terrain_columns != tuple(config.terrain_columns):
            # A server older than `terrain.columns` builds its default grid without a word.
            session.close()
            raise ProtocolError(
                f"asked for the grid columns {list(config.terrain_columns)} and the server "
                f"({spec.server_version}) built {list(spec.terrain_columns) or 'its default'}: "
                "it predates TerrainConfig.columns"
            )
        return session

    def evaluate(
        self,
        policy_onnx: bytes,
        scenario: str,
        *,
        num_envs: int = 0,
        seed: int = 0,
        record: bool = False,
        record_env: int | None = None,
        biped_policy_onnx: bytes = b"",
        task_overrides_toml: str = "",
    ) -> EvaluateResult:
        """Roll out an ONNX policy on the server over a named scenario.

        Args:
            policy_onnx: ONNX bytes, input f32 [batch, 3, 53], output f32 [batch, 12].
            scenario: Scenario name, e.g. ``"stairs_up_quad"``.
            num_envs: Trials (0: the scenario's default).
            seed: Seed of the rollout.
            record: Ask for a rerun recording.
            record_env: The trial the recording follows (default 0), numbered across the
                scenario's cases in the order the report lists their outcomes (a traversal's
                forward trials, then its backward ones); ``INVALID_ARGUMENT`` if the scenario
                runs fewer.
            biped_policy_onnx: Optional second policy for the two-policy baseline.
            task_overrides_toml: TOML overriding the server's task config for this evaluation
                (e.g. ``'physics.engine = "articulated"'``); the scenario sets the rest.
        """
        req = pb.EvaluateRequest(
            policy_onnx=policy_onnx,
            biped_policy_onnx=biped_policy_onnx,
            scenario=scenario,
            num_envs=num_envs,
            seed=seed,
            record=record,
            record_env=record_env,
            task_overrides_toml=task_overrides_toml,
        )
        resp = call(lambda: self.stub.Evaluate(req))
        return EvaluateResult(dict(resp.metrics), resp.report_json, bytes(resp.recording_rrd))

    def close(self) -> None:
        """Close the channel."""
        self.channel.close()


_END = object()


class _StepStream:
    """A long-lived ``StepStream`` call: one request in, one result out, in order."""

    def __init__(self, stub: Any) -> None:
        self._requests: queue.SimpleQueue[Any] = queue.SimpleQueue()
        self._responses: Any = stub.StepStream(iter(self._requests.get, _END))

    def ended(self) -> bool:
        """The server has already ended the call (say, after its stream idle timeout)."""
        return bool(self._responses.done())

    def step(self, request: Any) -> Any:
        self._requests.put(request)
        try:
            return next(self._responses)
        except grpc.RpcError as err:
            raise UnigaitError.from_rpc_error(err) from None
        except StopIteration:
            raise ProtocolError("the server ended the step stream") from None

    def close(self, timeout_s: float = 5.0) -> None:
        """Half-close the stream and wait for the server to end it (cancel after a timeout)."""
        self._requests.put(_END)
        done = threading.Event()
        self._responses.add_done_callback(lambda _: done.set())
        if not done.wait(timeout_s):
            self._responses.cancel()


class Session(ClosesOnExit):
    """A batch of envs on one server.

    Attributes:
        client: The connection.
        session_id: The server's id of the session.
        spec: Shapes, slices and constants of the session.
        initial: The first observations (after the initial reset).
    """

    def __init__(
        self,
        client: Client,
        session_id: str,
        spec: Spec,
        initial: StepResult,
        *,
        owns_client: bool = False,
    ) -> None:
        self.client = client
        self.session_id = session_id
        self.spec = spec
        self.initial = initial
        self._stream: _StepStream | None = None
        self._owns_client = owns_client
        self._closed = False

    @property
    def num_envs(self) -> int:
        """N."""
        return self.spec.num_envs

    def _request(
        self, actions: np.ndarray, reward_terms: bool, draw_envs: Sequence[int] = ()
    ) -> Any:
        return pb.StepRequest(
            session_id=self.session_id,
            actions=encode(actions),
            reward_terms=reward_terms,
            draw_envs=draw_envs,
        )

    def step(
        self, actions: np.ndarray, *, reward_terms: bool = False, draw_envs: Sequence[int] = ()
    ) -> StepResult:
        """One batched step over the session's stream (opened on first use).

        Args:
            actions: f32 [N, 12]; joint targets are default + action_scale * action.
            reward_terms: Include the per-term rewards even if the session does not by default.
            draw_envs: Envs whose body poses the result carries (``body_poses``), at most 64.

        Returns:
            The step result; ended envs are already reset (same-step autoreset).

        Raises:
            UnigaitError: The server refused the step (the stream is reopened on the next call).
        """
        if self._stream is not None and self._stream.ended():
            # The server closed an idle stream (a learner paused longer than the server's
            # --stream-idle-timeout) before this request: nothing was lost, so open a new one
            # instead of failing the step. The session itself lives on (--idle-timeout).
            self._stream = None
        if self._stream is None:
            self._stream = _StepStream(self.client.stub)
        try:
            msg = self._stream.step(self._request(actions, reward_terms, draw_envs))
        except (UnigaitError, ProtocolError):
            self._stream = None
            raise
        return StepResult.from_proto(msg, self.spec)

    def step_unary(self, actions: np.ndarray, *, reward_terms: bool = False) -> StepResult:
        """One batched step with the unary ``Step`` call (see :meth:`step` for the arguments)."""
        req = self._request(actions, reward_terms)
        return StepResult.from_proto(call(lambda: self.client.stub.Step(req)), self.spec)

    def reset(self, mask: np.ndarray | None = None) -> StepResult:
        """Reset every env, or those where ``mask`` (bool or u8 [N]) is set.

        Returns:
            A result whose ``obs`` holds the new first observations of the reset envs.
        """
        req = pb.ResetRequest(session_id=self.session_id)
        if mask is not None:
            req.mask.CopyFrom(encode(np.asarray(mask) != 0, "u1"))
        return StepResult.from_proto(call(lambda: self.client.stub.Reset(req)), self.spec)

    def close(self) -> None:
        """End the stream and free the session (idempotent; an already gone session is fine)."""
        if self._closed:
            return
        self._closed = True
        if self._stream is not None:
            self._stream.close()
            self._stream = None
        req = pb.CloseSessionRequest(session_id=self.session_id)
        try:
            call(lambda: self.client.stub.CloseSession(req))
        except UnigaitError as err:
            if err.code not in (grpc.StatusCode.NOT_FOUND, grpc.StatusCode.UNAVAILABLE):
                raise
        finally:
            if self._owns_client:
                self.client.close()
