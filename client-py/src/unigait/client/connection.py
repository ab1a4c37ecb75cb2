"""Channels to a server: plaintext on loopback, TLS and a bearer token beyond it.

A server started beyond loopback (``unigait-server serve --allow-remote --tls-cert C --tls-key K
--token-file T``) speaks TLS and refuses every ``Simulator`` call that lacks the metadata
``authorization: Bearer <token>``; gRPC's access-token call credentials send exactly that header.
Addresses may name the transport: ``https://host:port`` means TLS, ``http://host:port``
plaintext, a bare ``host:port`` TLS only when root certificates are given.
"""

from __future__ import annotations

import ipaddress
import os
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TypedDict

import grpc

#: Environment variable holding the bearer token (read by the CLI when no ``--token-file``).
TOKEN_ENV = "UNIGAIT_TOKEN"


class ConnectionOptions(TypedDict, total=False):
    """Keyword arguments of :class:`~unigait.client.Client` that choose the transport.

    Attributes:
        root_certificates: PEM CA bundle that signed the server's certificate (None: system
            roots); giving one means TLS.
        token: Bearer token sent with every call.
        tls_server_name: Name to check the server's certificate against, when it differs from
            the host in the address (e.g. connecting by IP to a certificate for a DNS name).
    """

    root_certificates: bytes | None
    token: str | None
    tls_server_name: str | None


@dataclass(frozen=True)
class Target:
    """A parsed server address.

    Attributes:
        target: ``host:port`` as gRPC takes it (the scheme removed).
        host: The host alone (no brackets for IPv6).
        tls: True for ``https://``, False for ``http://``, None when the address has no scheme.
    """

    target: str
    host: str
    tls: bool | None

    @property
    def is_loopback(self) -> bool:
        """Whether the host is ``localhost`` or a loopback IP address."""
        if self.host.lower() == "localhost":
            return True
        try:
            return ipaddress.ip_address(self.host).is_loopback
        except ValueError:
            return False


def parse_address(address: str) -> Target:
    """Split ``[https://|http://]host:port`` into the gRPC target, the host and the scheme's TLS.

    Example:
        >>> parse_address("https://sim.example.org:50051")
        Target(target='sim.example.org:50051', host='sim.example.org', tls=True)
        >>> parse_address("[::1]:50051").is_loopback
        True
    """
    address = address.strip()
    tls: bool | None = None
    for scheme, value in (("https://", True), ("http://", False)):
        if address.lower().startswith(scheme):
            address, tls = address[len(scheme) :].rstrip("/"), value
            break
    if not address:
        raise ValueError("empty server address")
    if address.startswith("["):  # [v6]:port
        host = address[1 : address.index("]")] if "]" in address else address[1:]
    elif address.count(":") == 1:
        host = address.split(":", 1)[0]
    else:  # a bare name, or a bare IPv6 address
        host = address
    return Target(address, host, tls)


def make_channel(
    address: str,
    *,
    root_certificates: bytes | None = None,
    token: str | None = None,
    tls_server_name: str | None = None,
    options: list[tuple[str, int | str]] | None = None,
) -> tuple[grpc.Channel, bool]:
    """Open the channel an address and the options call for.

    TLS when the address starts with ``https://`` or ``root_certificates`` are given (an
    ``http://`` address with root certificates is refused). The token rides on every call as
    ``authorization: Bearer <token>``: over TLS, or, in plaintext, only to a loopback host (gRPC's
    local credentials, which also check that the peer really is on this machine); a token in
    plaintext over the network is refused rather than sent.

    Args:
        address: ``[https://|http://]host:port``.
        root_certificates: PEM CA bundle for TLS (None with ``https://``: system roots).
        token: Bearer token.
        tls_server_name: Certificate name to verify instead of the address's host.
        options: More gRPC channel options.

    Returns:
        The channel and whether it uses TLS.

    Raises:
        ValueError: Contradicting options, or a token that would travel in plaintext.
    """
    parsed = parse_address(address)
    if parsed.tls is False and root_certificates is not None:
        raise ValueError(f"{address}: http:// (plaintext) contradicts TLS root certificates")
    if token is not None and (not token or token != token.strip() or "\n" in token):
        raise ValueError("the token is empty or has surrounding whitespace")
    tls = parsed.tls if parsed.tls is not None else root_certificates is not None
    opts = list(options or [])
    if tls:
        if tls_server_name:
            opts.append(("grpc.ssl_target_name_override", tls_server_name))
        creds = grpc.ssl_channel_credentials(root_certificates=root_certificates)
        if token is not None:
            creds = grpc.composite_channel_credentials(
                creds, grpc.access_token_call_credentials(token)
            )
        return grpc.secure_channel(parsed.target, creds, options=opts), True
    if token is None:
        return grpc.insecure_channel(parsed.target, options=opts), False
    if not parsed.is_loopback:
        raise ValueError(
            f"{address}: refusing to send the token in plaintext beyond this machine; use "
            "https://HOST:PORT (and root_certificates / --tls-ca for a private CA)"
        )
    local = grpc.local_channel_credentials(grpc.LocalConnectionType.LOCAL_TCP)
    creds = grpc.composite_channel_credentials(local, grpc.access_token_call_credentials(token))
    return grpc.secure_channel(parsed.target, creds, options=opts), False


def read_token_file(path: str | os.PathLike[str]) -> str:
    """The token in a file (surrounding whitespace removed, as the server reads its own).

    Raises:
        ValueError: The file is empty.
    """
    token = Path(path).read_text(encoding="utf-8").strip()
    if not token:
        raise ValueError(f"the token file {path} is empty")
    return token


def load_connection_options(
    tls_ca: str | os.PathLike[str] | None = None,
    token_file: str | os.PathLike[str] | None = None,
    environ: Mapping[str, str] | None = None,
) -> ConnectionOptions:
    """Connection options from files and the environment (what the CLI flags give).

    Args:
        tls_ca: PEM file of the CA that signed the server's certificate (means TLS).
        token_file: File holding the bearer token; without it, ``$UNIGAIT_TOKEN`` if set.
        environ: Environment to read (default ``os.environ``).

    Returns:
        Keyword arguments for :class:`~unigait.client.Client` or
        :func:`~unigait.client.open_session`.
    """
    env = os.environ if environ is None else environ
    opts: ConnectionOptions = {}
    if tls_ca is not None:
        opts["root_certificates"] = Path(tls_ca).read_bytes()
    if token_file is not None:
        opts["token"] = read_token_file(token_file)
    elif env.get(TOKEN_ENV, "").strip():
        opts["token"] = env[TOKEN_ENV].strip()
    return opts
