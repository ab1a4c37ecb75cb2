"""TLS and a bearer token for a pool's servers, and what the learner needs to reach them.

The server reads its certificate, key and token from files (``serve --tls-cert --tls-key
--token-file``), once, at start. Each of the three reaches a server actor one of two ways:

* **A path on every node** (``cert_file``, ``key_file``, ``token_file``; the default of the
  CLI): the cluster puts the files there, e.g. Kubernetes secrets mounted into every worker pod
  (``deploy/k8s/raycluster.yaml``), a shared volume, or config management. The secrets then never
  pass through Ray, and the kubelet can rotate them. This is the way for production clusters.
* **Shipped contents** (``cert_pem``, ``key_pem``, ``token``; see
  :meth:`ServerCredentials.shipped`): for clusters with no way to place files on their nodes (and
  the tests). They are never in an actor's creation arguments, which Ray keeps in its control
  store (GCS, persisted to Redis when GCS fault tolerance is on) for as long as the actor may be
  restarted: the pool sends them in the call that starts each server (``ServerActor.start``, a
  direct call from the driver to the actor that Ray does not keep once it returned), again after
  a restart. The actor hands them to the server through pipes (``--token-file /dev/fd/N``), so
  they are never written to a file, not even in ``/dev/shm``, and nothing is left behind by an
  actor killed while its server starts. Ray has no access control of its own: whoever can submit
  work to the cluster can read the nodes' files anyway, so this is no weaker than the cluster's
  own boundary.

The token the learner sends is :attr:`ServerCredentials.token`; without ``token_file`` the
servers are given the same one (shipped). The learner verifies the servers' certificates with
``ca`` (default: the shipped certificate itself, for a self-signed one), against
``tls_server_name`` when the certificate names something other than the address the learner
dials (pod IPs change; a certificate for one DNS name and this override fit any pod).
"""

from __future__ import annotations

import contextlib
import os
import threading
from dataclasses import dataclass, field
from pathlib import Path

from unigait.client.connection import ConnectionOptions

#: Shortest token the server accepts (``MIN_TOKEN_LEN`` in ``server/service/src/server.rs``).
MIN_TOKEN_LEN = 16


def check_token(token: str) -> None:
    """Refuse a token the server would refuse (at least 16 visible ASCII characters).

    Raises:
        ValueError: Too short, or has spaces or non-ASCII characters.
    """
    if len(token) < MIN_TOKEN_LEN:
        raise ValueError(
            f"the bearer token has {len(token)} characters; the server needs at least "
            f"{MIN_TOKEN_LEN} (e.g. `openssl rand -hex 32`)"
        )
    if not all(c.isascii() and c.isprintable() and not c.isspace() for c in token):
        raise ValueError("the bearer token must be visible ASCII characters only")


@dataclass(frozen=True)
class ServerCredentials:
    """TLS certificate, key and bearer token of a pool's servers (see the module docstring).

    Give the certificate and the key each either as a path on every node (``*_file``) or as PEM
    contents (``*_pem``), or neither (no TLS: loopback only). The servers' token is
    ``token_file`` on the nodes if given, else :attr:`token` (shipped).

    Attributes:
        cert_file: Server certificate (PEM) at this path on every node.
        key_file: Its private key at this path on every node.
        token_file: The servers' bearer token at this path on every node.
        cert_pem: Server certificate (chain) contents, shipped to the actors.
        key_pem: Private key contents, shipped to the actors.
        token: The token the learner sends (and the servers' token when no ``token_file``).
        ca: PEM CA bundle the learner verifies the servers with (None: ``cert_pem``, which must
            then be given: a self-signed certificate is its own CA).
        tls_server_name: Name to check the certificates against instead of the dialled address.
    """

    cert_file: str | None = None
    key_file: str | None = None
    token_file: str | None = None
    cert_pem: bytes | None = field(default=None, repr=False)
    key_pem: bytes | None = field(default=None, repr=False)
    token: str | None = field(default=None, repr=False)
    ca: bytes | None = field(default=None, repr=False)
    tls_server_name: str | None = None

    def __post_init__(self) -> None:
        if self.cert_file is not None and self.cert_pem is not None:
            raise ValueError("give the certificate as cert_file or cert_pem, not both")
        if self.key_file is not None and self.key_pem is not None:
            raise ValueError("give the key as key_file or key_pem, not both")
        has_key = self.key_file is not None or self.key_pem is not None
        if self.tls != has_key:
            raise ValueError("the TLS certificate and key go together")
        if not self.tls and (self.ca is not None or self.tls_server_name):
            raise ValueError("ca and tls_server_name need a server certificate (TLS)")
        if self.tls and self.ca is None and self.cert_pem is None:
            raise ValueError(
                "the learner needs the CA that signed the servers' certificate (ca=..., CLI "
                "--tls-ca; for a public CA, the system bundle, e.g. "
                "/etc/ssl/certs/ca-certificates.crt)"
            )
        if self.token is not None:
            check_token(self.token)

    @classmethod
    def shipped(
        cls,
        cert: str | os.PathLike[str],
        key: str | os.PathLike[str],
        token: str,
        *,
        ca: str | os.PathLike[str] | None = None,
        tls_server_name: str | None = None,
    ) -> ServerCredentials:
        """Read local files whose contents travel to the actors (see the module docstring).

        Args:
            cert: Server certificate (PEM) on this machine.
            key: Its private key on this machine.
            token: The bearer token (servers and learner).
            ca: CA the learner trusts (default: the certificate itself, if self-signed).
            tls_server_name: See the class.
        """
        return cls(
            cert_pem=Path(cert).read_bytes(),
            key_pem=Path(key).read_bytes(),
            token=token,
            ca=Path(ca).read_bytes() if ca is not None else None,
            tls_server_name=tls_server_name,
        )

    @property
    def tls(self) -> bool:
        """Whether the servers speak TLS."""
        return self.cert_file is not None or self.cert_pem is not None

    @property
    def server_token(self) -> bool:
        """Whether the servers require a token."""
        return self.token_file is not None or self.token is not None

    def connection_options(self) -> ConnectionOptions:
        """The learner's :class:`~unigait.client.Client` keyword arguments."""
        opts: ConnectionOptions = {}
        if self.tls:
            opts["root_certificates"] = self.ca if self.ca is not None else self.cert_pem
            if self.tls_server_name:
                opts["tls_server_name"] = self.tls_server_name
        if self.token is not None:
            opts["token"] = self.token
        return opts

    def health_options(self) -> ConnectionOptions:
        """:func:`unigait.ray.health.check_health` options: TLS, no token (health needs none)."""
        opts = self.connection_options()
        opts.pop("token", None)
        return opts

    def server_flags(self) -> tuple[list[str], SecretPipes]:
        """On the actor's node: the ``serve`` flags, shipped contents read from pipes.

        Returns:
            The flags and the pipes they name (``/dev/fd/N``): pass ``pipes.fds`` to the
            server's process (``pass_fds``), then call ``pipes.send()`` once it is spawned, or
            ``pipes.close()`` if it was not.

        Raises:
            FileNotFoundError: A ``*_file`` is not on this node.
        """
        for path in (self.cert_file, self.key_file, self.token_file):
            if path is not None and not Path(path).is_file():
                raise FileNotFoundError(f"{path} is not on this node")
        token = None if self.token_file is not None else self.token
        shipped = {
            "--tls-cert": self.cert_pem,
            "--tls-key": self.key_pem,
            "--token-file": token.encode() if token is not None else None,
        }
        pipes = SecretPipes({k: v for k, v in shipped.items() if v is not None})
        flags: list[str] = []
        for flag, node_path in (
            ("--tls-cert", self.cert_file),
            ("--tls-key", self.key_file),
            ("--token-file", self.token_file),
        ):
            if node_path is not None:
                flags += [flag, node_path]
        return flags + pipes.flags, pipes

    @classmethod
    def from_files(
        cls,
        *,
        tls_ca: str | os.PathLike[str] | None = None,
        token: str | None = None,
        server_cert: str | None = None,
        server_key: str | None = None,
        server_token_file: str | None = None,
        tls_server_name: str | None = None,
    ) -> ServerCredentials | None:
        """What ``train --ray`` builds from its flags (None: no credentials at all).

        Args:
            tls_ca: The learner's CA file (``--tls-ca``, on this machine).
            token: The learner's token (``--token-file`` / ``$UNIGAIT_TOKEN``).
            server_cert: ``--server-tls-cert``, a path on every node.
            server_key: ``--server-tls-key``, a path on every node.
            server_token_file: ``--server-token-file``, a path on every node (default: the
                learner's token is shipped to the servers).
            tls_server_name: ``--tls-server-name``.
        """
        if not any((tls_ca, token, server_cert, server_key, server_token_file)):
            return None
        return cls(
            cert_file=server_cert,
            key_file=server_key,
            token_file=server_token_file,
            token=token,
            ca=Path(tls_ca).read_bytes() if tls_ca is not None else None,
            tls_server_name=tls_server_name,
        )


class SecretPipes:
    """Shipped contents handed to a child process through pipes, never through a file.

    Each content gets a pipe whose read end the child inherits and opens as ``/dev/fd/N`` (the
    server reads its files once, at start); a thread writes the content into the write end and
    closes it. A child that dies first closes the read end, and the write fails and ends.

    Attributes:
        flags: ``[flag, "/dev/fd/N", ...]`` for each content.
        fds: The read ends (``subprocess.Popen(pass_fds=...)``).
    """

    def __init__(self, contents: dict[str, bytes]) -> None:
        self.flags: list[str] = []
        self.fds: list[int] = []
        self._writes: list[tuple[int, bytes]] = []
        for flag, data in contents.items():
            read_end, write_end = os.pipe()
            self.flags += [flag, f"/dev/fd/{read_end}"]
            self.fds.append(read_end)
            self._writes.append((write_end, data))

    def send(self) -> None:
        """Once the child is spawned: close the read ends here, write the contents."""
        for fd in self.fds:
            os.close(fd)
        self.fds = []
        for fd, data in self._writes:
            threading.Thread(target=_write_and_close, args=(fd, data), daemon=True).start()
        self._writes = []

    def close(self) -> None:
        """Close every end (the child was not spawned)."""
        for fd in [*self.fds, *(w for w, _ in self._writes)]:
            with contextlib.suppress(OSError):
                os.close(fd)
        self.fds, self._writes = [], []


def _write_and_close(fd: int, data: bytes) -> None:
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
    except OSError:  # the child exited without reading (its own error says why)
        pass
