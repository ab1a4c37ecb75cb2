"""The standard gRPC health check (``grpc.health.v1.Health/Check``) without extra packages.

The request and reply are tiny protobuf messages, encoded here by hand so that neither
``grpcio-health-checking`` nor generated stubs are needed: ``HealthCheckRequest{service}`` and
``HealthCheckResponse{status}`` with ``status = 1`` meaning SERVING. Over TLS the checks need
the CA (and, if the certificate names another host, the name); the health service itself needs
no token, also beyond loopback (the server leaves it open for probes).
"""

from __future__ import annotations

import re
import time

import grpc

from unigait.client.connection import make_channel

_CHECK = "/grpc.health.v1.Health/Check"
_SERVING = b"\x08\x01"  # field 1 (status), varint 1 (SERVING)
_TLS_FAILURE = re.compile(r"handshake failed|verification check failed", re.IGNORECASE)


def _request(service: str) -> bytes:
    name = service.encode()
    if not name:
        return b""
    if len(name) > 127:
        raise ValueError(f"service name too long for this encoder: {service!r}")
    return b"\x0a" + bytes([len(name)]) + name  # field 1 (service), length-delimited


def _describe(err: grpc.RpcError) -> str:
    if isinstance(err, grpc.Call):
        return f"{err.code().name}: {err.details()}"
    return str(err)


def probe_health(
    address: str,
    *,
    service: str = "",
    timeout_s: float = 2.0,
    root_certificates: bytes | None = None,
    tls_server_name: str | None = None,
) -> str | None:
    """Ask the server at ``address`` whether ``service`` is SERVING; say why not.

    Args:
        address: ``[https://|http://]host:port``.
        service: Service name, e.g. ``"unigait.v1.Simulator"``; empty for the server.
        timeout_s: Deadline of the call (it waits for the channel to come up within it).
        root_certificates: PEM CA bundle: check over TLS (the health service needs no token).
        tls_server_name: Certificate name to verify instead of the address's host.

    Returns:
        None if the reply says SERVING, else what went wrong (gRPC status and details).
    """
    channel, _ = make_channel(
        address, root_certificates=root_certificates, tls_server_name=tls_server_name
    )
    with channel:
        check = channel.unary_unary(_CHECK)  # bytes in, bytes out (no serializers)
        try:
            reply = check(_request(service), timeout=timeout_s, wait_for_ready=True)
        except grpc.RpcError as err:
            why = _describe(err)
            if why.startswith("DEADLINE_EXCEEDED"):
                # The channel never came up; a call that does not wait says why (refused,
                # TLS handshake failed, ...).
                try:
                    check(_request(service), timeout=0.5)
                except grpc.RpcError as again:
                    why = _describe(again)
            return why
    if bytes(reply)[:2] != _SERVING:
        return f"status {bytes(reply)!r} (not SERVING)"
    return None


def check_health(
    address: str,
    *,
    service: str = "",
    timeout_s: float = 2.0,
    root_certificates: bytes | None = None,
    tls_server_name: str | None = None,
) -> bool:
    """Whether the server at ``address`` says ``service`` is SERVING (see :func:`probe_health`).

    Returns:
        True if the reply says SERVING; False on any error or another status.
    """
    return (
        probe_health(
            address,
            service=service,
            timeout_s=timeout_s,
            root_certificates=root_certificates,
            tls_server_name=tls_server_name,
        )
        is None
    )


def wait_healthy(
    address: str,
    timeout_s: float,
    *,
    service: str = "",
    root_certificates: bytes | None = None,
    tls_server_name: str | None = None,
) -> None:
    """Poll :func:`probe_health` until it passes.

    Raises:
        TimeoutError: ``address`` did not answer SERVING within ``timeout_s`` (with the last
            reason).
        ConnectionError: The TLS handshake failed twice in a row (an untrusted certificate, a
            wrong name), which waiting does not mend.
    """
    deadline = time.monotonic() + timeout_s
    tls_failures = 0
    while True:
        remaining = deadline - time.monotonic()
        why = probe_health(
            address,
            service=service,
            timeout_s=max(min(remaining, 2.0), 0.1),
            root_certificates=root_certificates,
            tls_server_name=tls_server_name,
        )
        if why is None:
            return
        tls_failures = tls_failures + 1 if _TLS_FAILURE.search(why) else 0
        if tls_failures >= 2:  # an answer, not a server still starting: waiting will not help
            raise ConnectionError(
                f"{address}: the TLS handshake failed: {why} (check the CA the learner trusts, "
                "--tls-ca, and the name checked, --tls-server-name)"
            )
        if time.monotonic() >= deadline:
            tls = " over TLS (check the CA and the server name)" if root_certificates else ""
            raise TimeoutError(
                f"{address} did not report SERVING{tls} within {timeout_s} s; last: {why}"
            )
        time.sleep(0.1)
