"""The Python client against a real server with TLS and a bearer token, over loopback.

The server is started as for serving beyond loopback (``--tls-cert --tls-key --token-file``; it
accepts them on 127.0.0.1 without ``--allow-remote``) with a self-signed certificate for
``localhost`` and ``127.0.0.1`` made by the ``openssl`` command, as ``client-rs/tests/loopback.rs``
makes its own.
"""

from __future__ import annotations

import shutil
import subprocess
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import grpc
import numpy as np
import pytest
from unigait.cli import main
from unigait.client import (
    Client,
    Session,
    SessionConfig,
    ShardedSession,
    UnigaitError,
    load_connection_options,
    open_session,
    parse_address,
)

TOKEN = "t0ken-for-the-tls-test"

#: Short waits for channels that cannot come up (plaintext to TLS, untrusted certificate).
REFUSED_TIMEOUT_S = 1.5


@dataclass(frozen=True)
class TlsServer:
    """A running TLS + token server and the client-side files."""

    address: str  # 127.0.0.1:PORT
    ca: bytes  # the self-signed certificate, which is its own CA
    ca_file: Path
    token_file: Path

    @property
    def port(self) -> str:
        return self.address.rsplit(":", 1)[1]


def _self_signed(directory: Path) -> tuple[Path, Path]:
    """A self-signed certificate for localhost and 127.0.0.1 (openssl, valid one day)."""
    cert, key = directory / "cert.pem", directory / "key.pem"
    subprocess.run(
        [
            "openssl",
            "req",
            "-x509",
            "-newkey",
            "rsa:2048",
            "-nodes",
            "-days",
            "1",
            "-subj",
            "/CN=localhost",
            "-addext",
            "subjectAltName=DNS:localhost,IP:127.0.0.1",
            "-addext",
            "basicConstraints=critical,CA:FALSE",
            "-addext",
            "extendedKeyUsage=serverAuth",
            "-keyout",
            str(key),
            "-out",
            str(cert),
        ],
        check=True,
        capture_output=True,
    )
    return cert, key


@pytest.fixture(scope="module")
def tls_server(
    start_server: Callable[..., str], tmp_path_factory: pytest.TempPathFactory
) -> TlsServer:
    if shutil.which("openssl") is None:
        pytest.skip("the openssl command is needed to make a test certificate")
    directory = tmp_path_factory.mktemp("tls")
    cert, key = _self_signed(directory)
    token_file = directory / "token"
    token_file.write_text(TOKEN + "\n")  # the server strips the newline, and so do we
    address = start_server(
        "--tls-cert", str(cert), "--tls-key", str(key), "--token-file", str(token_file)
    )
    return TlsServer(address, cert.read_bytes(), cert, token_file)


def test_plaintext_client_is_refused(tls_server: TlsServer) -> None:
    with pytest.raises(UnigaitError) as err:
        Client(tls_server.address, token=TOKEN, connect_timeout_s=REFUSED_TIMEOUT_S)
    assert err.value.code == grpc.StatusCode.UNAVAILABLE
    assert "plaintext" in err.value.details and "https://" in err.value.details


def test_untrusted_certificate_is_refused(tls_server: TlsServer) -> None:
    """https:// alone trusts the system roots, which did not sign our certificate."""
    with pytest.raises(UnigaitError) as err:
        Client(f"https://{tls_server.address}", connect_timeout_s=REFUSED_TIMEOUT_S)
    assert err.value.code == grpc.StatusCode.UNAVAILABLE
    assert "TLS" in err.value.details


def test_tls_without_token_is_unauthenticated(tls_server: TlsServer) -> None:
    with Client(tls_server.address, root_certificates=tls_server.ca) as client:
        assert client.tls
        with pytest.raises(UnigaitError) as err:
            client.server_info()
        assert err.value.code == grpc.StatusCode.UNAUTHENTICATED
        assert err.value.code_name == "UNAUTHENTICATED"
        assert "Bearer" in err.value.details and "--token-file" in err.value.details
        with pytest.raises(UnigaitError) as err:
            client.create_session(SessionConfig(num_envs=1))
        assert err.value.code == grpc.StatusCode.UNAUTHENTICATED


def test_wrong_token_is_unauthenticated(tls_server: TlsServer) -> None:
    client = Client(tls_server.address, root_certificates=tls_server.ca, token="guess")
    with client, pytest.raises(UnigaitError) as err:
        client.server_info()
    assert err.value.code == grpc.StatusCode.UNAUTHENTICATED
    assert "wrong bearer token" in err.value.details


def test_tls_with_token_opens_a_session_and_steps(tls_server: TlsServer) -> None:
    with open_session(
        f"https://localhost:{tls_server.port}",  # the certificate's DNS name
        SessionConfig(num_envs=2, seed=3),
        root_certificates=tls_server.ca,
        token=TOKEN,
    ) as session:
        assert isinstance(session, Session) and session.client.tls
        assert session.client.server_info().protocol_version == "v1"
        # Unary first: once the session has a step stream, steps go there.
        assert session.step_unary(np.zeros((2, 12), dtype=np.float32)).obs.shape == (2, 53)
        for _ in range(3):  # the step stream carries the token too
            result = session.step(np.zeros((2, 12), dtype=np.float32))
            assert result.obs.shape == (2, 53) and np.isfinite(result.obs).all()
        assert session.reset().obs.shape == (2, 53)


def test_sharded_session_and_reconnect_keep_the_credentials(tls_server: TlsServer) -> None:
    with open_session(
        [tls_server.address, tls_server.address],
        SessionConfig(num_envs=3),
        root_certificates=tls_server.ca,
        token=TOKEN,
    ) as session:
        assert isinstance(session, ShardedSession)
        assert session.step(np.zeros((3, 12), dtype=np.float32)).obs.shape == (3, 53)
        client = session.sessions[0].client
        with client.connect_to(f"https://localhost:{tls_server.port}") as other:
            assert other.tls and other.server_info().protocol_version == "v1"


def test_cli_info_with_tls_ca_and_token_file(
    tls_server: TlsServer, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.delenv("UNIGAIT_TOKEN", raising=False)
    server = ["--server", tls_server.address, "--tls-ca", str(tls_server.ca_file)]
    assert main(["info", *server, "--token-file", str(tls_server.token_file)]) == 0
    assert "protocol_version" in capsys.readouterr().out
    assert main(["info", *server]) == 2  # no token: the server's refusal, as an error line
    assert "UNAUTHENTICATED" in capsys.readouterr().err
    monkeypatch.setenv("UNIGAIT_TOKEN", TOKEN)
    assert main(["info", *server]) == 0


def test_connection_options_from_files_and_environment(tmp_path: Path) -> None:
    (tmp_path / "token").write_text("  abc\n")
    (tmp_path / "ca.pem").write_bytes(b"PEM")
    opts = load_connection_options(tmp_path / "ca.pem", tmp_path / "token", {})
    assert opts == {"root_certificates": b"PEM", "token": "abc"}
    assert load_connection_options(None, None, {"UNIGAIT_TOKEN": "xyz"}) == {"token": "xyz"}
    assert load_connection_options(None, tmp_path / "token", {"UNIGAIT_TOKEN": "xyz"}) == {
        "token": "abc"  # the file wins
    }
    assert load_connection_options(None, None, {}) == {}
    (tmp_path / "empty").write_text("\n")
    with pytest.raises(ValueError, match="empty"):
        load_connection_options(None, tmp_path / "empty", {})


def test_addresses_and_refused_combinations() -> None:
    assert parse_address("https://h.example:443/").target == "h.example:443"
    assert parse_address("https://h.example:443").tls is True
    assert parse_address("http://127.0.0.1:1").tls is False
    assert parse_address("10.0.0.2:50051").tls is None
    assert parse_address("localhost:1").is_loopback and parse_address("[::1]:1").is_loopback
    assert not parse_address("10.0.0.2:50051").is_loopback
    with pytest.raises(ValueError, match="plaintext"):  # a token never crosses in plaintext
        Client("10.0.0.2:50051", token=TOKEN, connect_timeout_s=None)
    with pytest.raises(ValueError, match="contradicts"):
        Client("http://10.0.0.2:50051", root_certificates=b"PEM", connect_timeout_s=None)
    with Client("https://10.0.0.2:50051", token=TOKEN, connect_timeout_s=None) as client:
        assert client.tls  # not connected: the channel is lazy


def test_token_in_plaintext_on_loopback(
    start_server: Callable[..., str], tls_server: TlsServer
) -> None:
    """A token-only server on loopback: gRPC local credentials carry the token in plaintext."""
    address = start_server("--token-file", str(tls_server.token_file))
    with Client(address, token=TOKEN) as client:
        assert not client.tls and client.server_info().protocol_version == "v1"
    with Client(address) as client, pytest.raises(UnigaitError) as err:
        client.server_info()
    assert err.value.code == grpc.StatusCode.UNAUTHENTICATED
