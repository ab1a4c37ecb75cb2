"""Fixtures of the unit tests (no server binary needed)."""

from __future__ import annotations

from collections.abc import Iterator

import pytest
from fakes import start_fake_server


@pytest.fixture
def fake_server() -> Iterator[tuple[str, object]]:
    """An in-process fake gRPC server: (address, servicer)."""
    server, address, servicer = start_fake_server()
    yield address, servicer
    server.stop(grace=None)
