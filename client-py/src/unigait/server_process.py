"""Start a local ``unigait-server`` binary as a child process (tests, ``train --spawn-server``)."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import threading
import time
from collections import deque
from pathlib import Path
from types import TracebackType

_LISTENING = re.compile(r"listening on (\S+:\d+)")
#: A tracing line at WARN or ERROR level (the server logs without colour to a pipe).
_ALERT = re.compile(r"^\S+\s+(WARN|ERROR)\s")


def default_server_bin() -> Path:
    """Path of the server binary.

    ``$UNIGAIT_SERVER_BIN``; else the repository's ``target/release/unigait-server`` (editable
    installs) or ``unigait-server`` on ``PATH``.
    """
    env = os.environ.get("UNIGAIT_SERVER_BIN")
    if env:
        return Path(env)
    in_repo = Path(__file__).resolve().parents[3] / "target" / "release" / "unigait-server"
    on_path = shutil.which("unigait-server")
    if not in_repo.is_file() and on_path:
        return Path(on_path)
    return in_repo


class LocalServer:
    """A ``unigait-server serve`` child process on 127.0.0.1 with an OS-picked port.

    Args:
        binary: Path of the server binary.
        extra_args: More flags for ``serve`` (e.g. ``["--max-envs", "4096"]``).
        startup_timeout_s: How long to wait for its ``listening on`` line.

    Attributes:
        address: ``127.0.0.1:PORT`` once started.
    """

    def __init__(
        self,
        binary: str | Path | None = None,
        extra_args: list[str] | None = None,
        startup_timeout_s: float = 60.0,
    ) -> None:
        self.binary = Path(binary) if binary is not None else default_server_bin()
        self.extra_args = list(extra_args or [])
        self.startup_timeout_s = startup_timeout_s
        self.address = ""
        self.output: deque[str] = deque(maxlen=200)
        self._proc: subprocess.Popen[str] | None = None

    def start(self) -> str:
        """Start the server and return its address.

        Raises:
            FileNotFoundError: The binary does not exist.
            RuntimeError: It exited or did not report its address in time.
        """
        if not self.binary.is_file():
            raise FileNotFoundError(f"unigait server binary not found: {self.binary}")
        # The server ends when its stdin does: this process holds the pipe's other end, so a
        # learner killed without cleaning up (SIGKILL, OOM) takes its server with it. No code
        # runs in the child before exec (a preexec_fn there could deadlock on a lock held by
        # one of this process's other threads at the fork, gRPC's among them).
        cmd = [str(self.binary), "serve", "--addr", "127.0.0.1:0", "--exit-on-stdin-eof"]
        cmd += self.extra_args
        self._proc = subprocess.Popen(
            cmd,
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
            bufsize=1,
        )
        found = threading.Event()

        def drain() -> None:
            assert self._proc is not None and self._proc.stdout is not None
            for line in self._proc.stdout:
                self.output.append(line.rstrip("\n"))
                if _ALERT.search(line):  # a warning reaches the run's log, not just the tail
                    print(f"unigait-server: {line.rstrip()}", file=sys.stderr, flush=True)
                m = _LISTENING.search(line)
                if m and not found.is_set():
                    self.address = m.group(1)
                    found.set()

        threading.Thread(target=drain, daemon=True, name="unigait-server-log").start()
        deadline = time.monotonic() + self.startup_timeout_s
        while not found.wait(0.05):
            if self._proc.poll() is not None or time.monotonic() > deadline:
                self.stop()
                tail = "\n".join(self.output)
                raise RuntimeError(f"{' '.join(cmd)} did not start; its output:\n{tail}")
        return self.address

    def stop(self) -> None:
        """Terminate the server (SIGTERM, then SIGKILL after 10 s)."""
        if self._proc is None:
            return
        if self._proc.poll() is None:
            self._proc.terminate()
            try:
                self._proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self._proc.kill()
                self._proc.wait()
        self._proc = None

    def __enter__(self) -> LocalServer:
        self.start()
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.stop()
