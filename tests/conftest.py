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


def _release_binary(env_var: str, name: str, what: str, build: str) -> Path:
    """``$env_var``, else ``target/release/<name>``; the test skips, saying so, when missing."""
    env = os.environ.get(env_var)
    path = Path(env) if env else REPO / "target" / "release" / name
    if not path.is_file():
        pytest.skip(f"{what} not found at {path}: build it with `{build}` or set {env_var}")
    return path


@pytest.fixture(scope="session")
def server_bin() -> Path:
    return _release_binary(
        "UNIGAIT_SERVER_BIN", "unigait-server", "unigait server binary", "cargo build --release"
    )


@pytest.fixture(scope="session")
def crosscheck_bin() -> Path:
    return _release_binary(
        "UNIGAIT_CROSSCHECK_BIN",
        "unigait-crosscheck",
        "cross-check driver",
        "cargo build --release -p unigait-crosscheck",
    )


@pytest.fixture(scope="session")
def learner_bin() -> Path:
    return _release_binary(
        "UNIGAIT_LEARNER_BIN",
        "unigait-learner",
        "unigait-learner",
        "cargo build --release --workspace",
    )


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
