"""End-to-end fixtures: the real ``unigait-server`` binary as a child process.

The binary comes from ``$UNIGAIT_SERVER_BIN`` (default ``target/release/unigait-server``), the
MuJoCo cross-checks' driver from ``$UNIGAIT_CROSSCHECK_BIN`` (default
``target/release/unigait-crosscheck``); the tests skip, saying so, only when one does not exist
(scripts/test.sh always builds both first).
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
from unigait.server_process import LocalServer

REPO = Path(__file__).resolve().parents[1]


def _server_bin() -> Path:
    env = os.environ.get("UNIGAIT_SERVER_BIN")
    return Path(env) if env else REPO / "target" / "release" / "unigait-server"


@pytest.fixture(scope="session")
def server_bin() -> Path:
    path = _server_bin()
    if not path.is_file():
        pytest.skip(
            f"unigait server binary not found at {path}: build it with "
            "`cargo build --release` or set UNIGAIT_SERVER_BIN"
        )
    return path


@pytest.fixture(scope="session")
def crosscheck_bin() -> Path:
    env = os.environ.get("UNIGAIT_CROSSCHECK_BIN")
    path = Path(env) if env else REPO / "target" / "release" / "unigait-crosscheck"
    if not path.is_file():
        pytest.skip(
            f"cross-check driver not found at {path}: build it with "
            "`cargo build --release -p unigait-crosscheck` or set UNIGAIT_CROSSCHECK_BIN"
        )
    return path


@pytest.fixture(scope="session")
def start_server(server_bin: Path) -> Iterator[Callable[..., str]]:
    """Start servers on demand (127.0.0.1, OS-picked port); all are stopped at the end."""
    started: list[LocalServer] = []

    def start(*extra_args: str) -> str:
        server = LocalServer(server_bin, list(extra_args))
        started.append(server)
        return server.start()

    yield start
    for server in started:
        server.stop()


@pytest.fixture(scope="session")
def server(start_server: Callable[..., str]) -> str:
    """Address of one server shared by the tests."""
    return start_server("--max-envs", "1024")
