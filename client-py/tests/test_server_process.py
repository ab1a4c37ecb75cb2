"""A local server's warnings reach the run's log; its other output stays in the tail kept."""

from __future__ import annotations

import stat
import time
from pathlib import Path

import pytest

from unigait.server_process import LocalServer

FAKE = """#!/bin/sh
echo "2026-11-26T23:00:00.000000Z  INFO unigait_server: listening on 127.0.0.1:5"
echo "2026-11-26T23:00:01.000000Z  WARN unigait_sim::env::group: physics blow-up: env reset env=3"
echo "2026-11-26T23:00:02.000000Z ERROR unigait_server::service: something broke"
echo "a line that names WARN in passing"
exec sleep 30
"""


def test_warnings_and_errors_are_forwarded_to_stderr(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    fake = tmp_path / "fake-server"
    fake.write_text(FAKE)
    fake.chmod(fake.stat().st_mode | stat.S_IEXEC)
    with LocalServer(fake) as server:
        assert server.address == "127.0.0.1:5"
        deadline = time.monotonic() + 10.0
        while len(server.output) < 4 and time.monotonic() < deadline:
            time.sleep(0.05)
    quoted = [line.split('"')[1] for line in FAKE.splitlines()[2:4]]  # the WARN and ERROR lines
    expected = ["unigait-server: " + line for line in quoted]
    assert capsys.readouterr().err.splitlines() == expected
    assert len(server.output) == 4  # every line is in the tail kept
