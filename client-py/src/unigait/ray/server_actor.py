"""One ``unigait-server`` process owned by a Ray actor: the two live and die together.

The actor's :meth:`~ServerActor.start` (called by the pool, with the credentials, which are
therefore never among the actor's creation arguments that Ray keeps) starts ``unigait-server
serve --addr HOST:0 --threads K`` on the node Ray placed it on and reads the address from the
server's ``listening on ADDR`` line. A watcher thread owns the process for its whole life:

* the server dies (crash, OOM kill, ``kill -9``): the actor process exits at once, so that Ray
  restarts the actor (``max_restarts``), and the pool starts a new server in the restarted actor
  (a new port);
* the actor dies (``ray.kill``, the driver ends, the worker crashes): the kernel kills the server
  (``PR_SET_PDEATHSIG``, set in the child for the watcher thread that spawned it, which lives
  exactly as long as the server), so no server outlives its actor.

This module imports neither torch nor the learner: an actor's worker loads only the client.
"""

from __future__ import annotations

import ctypes
import os
import re
import shutil
import signal
import subprocess
import sys
import threading
from collections import deque
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from unigait.client.connection import parse_address
from unigait.ray.credentials import SecretPipes, ServerCredentials
from unigait.server_process import default_server_bin

_LISTENING = re.compile(r"listening on (\S+):(\d+)")
#: Environment variable naming the pool that started a server (for leak checks by process).
POOL_ID_ENV = "UNIGAIT_RAY_POOL"
_PR_SET_PDEATHSIG = 1
try:  # looked up once here: the child must not dlopen or dlsym between fork and exec
    _PRCTL: Any = ctypes.CDLL(None, use_errno=True).prctl if sys.platform == "linux" else None
except (OSError, AttributeError):
    _PRCTL = None


def resolve_binary(binary: str | None) -> Path:
    """Find the server binary on this node.

    Args:
        binary: None: ``$UNIGAIT_SERVER_BIN``, else the repository's build (editable installs),
            else ``unigait-server`` on ``PATH``. A bare name (no ``/``): looked up on ``PATH``.
            A path: absolute, or relative to the actor's working directory (where a Ray
            ``runtime_env`` ``working_dir`` is unpacked).

    Raises:
        FileNotFoundError: Nothing executable there.
    """
    if binary is None:
        path = default_server_bin()
    elif "/" not in binary:
        found = shutil.which(binary)
        if found is None:
            raise FileNotFoundError(f"{binary!r} is not on PATH ({os.environ.get('PATH', '')})")
        path = Path(found)
    else:
        path = Path(binary).resolve()
    if not path.is_file() or not os.access(path, os.X_OK):
        raise FileNotFoundError(f"no executable unigait server at {path}")
    return path


def _die_with_parent() -> None:  # runs in the child between fork and exec
    if _PRCTL is not None:  # Linux; elsewhere shutdown relies on stop()
        _PRCTL(_PR_SET_PDEATHSIG, signal.SIGKILL)


class ServerActor:
    """A ``unigait-server serve`` child process (use it through ``ray.remote``, see the pool).

    The server starts with :meth:`start`.

    Args:
        binary: See :func:`resolve_binary` (resolved on the actor's node).
        threads: Env worker threads of the server (``--threads``): the actor's CPUs.
        host: Address to bind (``"127.0.0.1"``: loopback); None binds the node's IP. Beyond
            loopback the actor adds ``--allow-remote``, and the server then insists on TLS and
            a token (:meth:`start`'s ``credentials``).
        extra_args: More ``serve`` flags (``--max-envs``, ``--idle-timeout``, ...).
        startup_timeout_s: How long to wait for the ``listening on`` line.
        echo_output: Copy the server's output to the actor's stdout (Ray's worker log, and the
            driver's console when ``log_to_driver``).
        pool_id: Put in the server's environment as ``$UNIGAIT_RAY_POOL`` (leak checks).

    Raises:
        FileNotFoundError: No binary (the actor's creation fails, and Ray does not restart an
            actor whose constructor raised).
    """

    def __init__(
        self,
        binary: str | None = None,
        threads: int = 1,
        host: str | None = "127.0.0.1",
        extra_args: Sequence[str] = (),
        startup_timeout_s: float = 60.0,
        echo_output: bool = False,
        pool_id: str = "",
    ) -> None:
        import ray

        self._node_id = ray.get_runtime_context().get_node_id()
        self._node_ip = ray.util.get_node_ip_address()
        self._binary = resolve_binary(binary)
        bind = host if host is not None else self._node_ip
        bind_addr = f"[{bind}]:0" if ":" in bind else f"{bind}:0"
        remote = not parse_address(bind_addr).is_loopback
        self._serve = [
            str(self._binary),
            "serve",
            "--addr",
            bind_addr,
            "--threads",
            str(threads),
            *(["--allow-remote"] if remote and "--allow-remote" not in extra_args else []),
        ]
        self._extra_args = list(extra_args)
        self._cmd = [*self._serve, *self._extra_args]
        self._startup_timeout_s = startup_timeout_s
        self._env = {**os.environ, POOL_ID_ENV: pool_id} if pool_id else None
        self._threads = threads
        self._echo = echo_output
        self._tls = False
        self.output: deque[str] = deque(maxlen=200)
        self._address = ""
        self._started = False
        self._proc: subprocess.Popen[str] | None = None
        self._spawn_error: OSError | None = None
        self._pipes: SecretPipes | None = None
        self._ready = threading.Event()
        self._stopping = threading.Event()

    def start(self, credentials: ServerCredentials | None = None) -> dict[str, Any]:
        """Start the server (once; later calls return :meth:`info`).

        Args:
            credentials: TLS certificate, key and token: paths on this node, or shipped
                contents, which reach the server through pipes (never a file).

        Returns:
            :meth:`info`.

        Raises:
            FileNotFoundError: A credentials file is not on this node.
            RuntimeError: The server exited or said nothing in time.
        """
        if self._started:
            return self.info()
        self._started = True
        auth: list[str] = []
        if credentials is not None:
            self._tls = credentials.tls
            auth, self._pipes = credentials.server_flags()
        self._cmd = [*self._serve, *auth, *self._extra_args]
        threading.Thread(target=self._own, daemon=True, name="unigait-server").start()
        if not self._ready.wait(self._startup_timeout_s) or not self._address:
            self.stop()
            tail = "\n".join(self.output)
            raise RuntimeError(
                f"{' '.join(self._cmd)} did not start within {self._startup_timeout_s} s "
                f"({self._spawn_error or 'no listening line'}); its output:\n{tail}"
            )
        return self.info()

    def _own(self) -> None:
        """Spawn the server, read its output, and end the actor if the server dies on its own."""
        pipes = self._pipes or SecretPipes({})
        try:
            proc = subprocess.Popen(
                self._cmd,
                stdout=subprocess.PIPE,
                stderr=subprocess.STDOUT,
                stdin=subprocess.DEVNULL,
                env=self._env,
                text=True,
                bufsize=1,
                pass_fds=pipes.fds,
                preexec_fn=_die_with_parent,
            )
        except OSError as err:
            pipes.close()
            self._spawn_error = err
            self._ready.set()
            return
        pipes.send()
        self._proc = proc
        assert proc.stdout is not None
        for line in proc.stdout:
            line = line.rstrip("\n")
            self.output.append(line)
            if self._echo:
                print(line, flush=True)
            m = _LISTENING.search(line)
            if m and not self._address:
                host = m.group(1)
                if host in ("0.0.0.0", "[::]", "::"):
                    host = self._node_ip
                self._address = f"{host}:{m.group(2)}"
                self._ready.set()
        code = proc.wait()
        self._ready.set()
        if self._address and not self._stopping.is_set():
            print(
                f"unigait-server {self._address} (pid {proc.pid}) exited with {code}; "
                "ending its actor so that Ray restarts it",
                file=sys.stderr,
                flush=True,
            )
            os._exit(1)

    def info(self) -> dict[str, Any]:
        """Where the server runs.

        Returns:
            ``address``, ``pid``, ``node_id``, ``node_ip``, ``threads``, ``alive``, ``binary``,
            ``tls``.
        """
        proc = self._proc
        return {
            "address": self._address,
            "tls": self._tls,
            "pid": proc.pid if proc is not None else 0,
            "node_id": self._node_id,
            "node_ip": self._node_ip,
            "threads": self._threads,
            "alive": proc is not None and proc.poll() is None,
            "binary": str(self._binary),
        }

    def output_tail(self) -> list[str]:
        """The server's last output lines (up to 200)."""
        return list(self.output)

    def stop(self, timeout_s: float = 10.0) -> int | None:
        """Stop the server (SIGTERM, SIGKILL after ``timeout_s``); return its exit code."""
        self._stopping.set()
        proc = self._proc
        if proc is None:
            return None
        if proc.poll() is None:
            proc.terminate()
            try:
                proc.wait(timeout=timeout_s)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
        return proc.returncode
