"""The standard gRPC health check (``grpc.health.v1.Health/Check``) without extra packages.

The request and reply are tiny protobuf messages, encoded here by hand so that neither
``grpcio-health-checking`` nor generated stubs are needed: ``HealthCheckRequest{service}`` and
``HealthCheckResponse{status}`` with ``status = 1`` meaning SERVING.
"""

from __future__ import annotations

import time

import grpc

_CHECK = "/grpc.health.v1.Health/Check"
_SERVING = b"\x08\x01"  # field 1 (status), varint 1 (SERVING)


def _request(service: str) -> bytes:
    name = service.encode()
    if not name:
        return b""
    if len(name) > 127:
        raise ValueError(f"service name too long for this encoder: {service!r}")
    return b"\x0a" + bytes([len(name)]) + name  # field 1 (service), length-delimited


def check_health(address: str, *, service: str = "", timeout_s: float = 2.0) -> bool:
    """Ask the server at ``address`` whether ``service`` ("" = the whole server) is SERVING.

    Args:
        address: ``host:port`` (plaintext; the pool's servers are on loopback).
        service: Service name, e.g. ``"unigait.v1.Simulator"``; empty for the server.
        timeout_s: Deadline of the call (it waits for the channel to come up within it).

    Returns:
        True if the reply says SERVING; False on any error or another status.
    """
    with grpc.insecure_channel(address) as channel:
        check = channel.unary_unary(_CHECK)  # bytes in, bytes out (no serializers)
        try:
            reply = check(_request(service), timeout=timeout_s, wait_for_ready=True)
        except grpc.RpcError:
            return False
    return bytes(reply)[:2] == _SERVING


def wait_healthy(address: str, timeout_s: float, *, service: str = "") -> None:
    """Poll :func:`check_health` until it passes.

    Raises:
        TimeoutError: ``address`` did not answer SERVING within ``timeout_s``.
    """
    deadline = time.monotonic() + timeout_s
    while True:
        remaining = deadline - time.monotonic()
        if check_health(address, service=service, timeout_s=max(min(remaining, 2.0), 0.1)):
            return
        if time.monotonic() >= deadline:
            raise TimeoutError(f"{address} did not report SERVING within {timeout_s} s")
        time.sleep(0.1)
