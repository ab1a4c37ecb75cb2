"""The Rust learner against a gRPC core server (Python's ``grpcio``, the fake simulator).

gRPC core sends a stream's response headers only with its first response; a client that waits
for them before sending its first request deadlocks (the Rust client did until 2026-11-26). The
Rust learner is needed: ``$UNIGAIT_LEARNER_BIN`` or the repository's release build, else skip.
"""

from __future__ import annotations

import os
import subprocess
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]


def test_the_rust_learner_trains_against_a_grpc_core_server(fake_server, tmp_path):
    env = os.environ.get("UNIGAIT_LEARNER_BIN")
    binary = Path(env) if env else REPO / "target" / "release" / "unigait-learner"
    if not binary.is_file():
        pytest.skip(f"unigait-learner not found at {binary}: cargo build --release --workspace")
    address, servicer = fake_server
    run = tmp_path / "run"
    args = ["--recipe", "quad_flat", "--iterations", "2", "--num-envs", "4"]
    done = subprocess.run(
        [str(binary), "train", "--server", address, *args, "--log-dir", str(run)],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert done.returncode == 0, done.stderr[-2000:]
    rows = (run / "01_quad" / "progress.csv").read_text().splitlines()
    assert len(rows) == 3  # the header and two iterations, stepped over the stream
    assert len(servicer.task_overrides) == 1  # one session, on the fake
