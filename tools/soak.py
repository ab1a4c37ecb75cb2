"""Soak a unigait server: misbehaving clients beside one well-behaved learner.

One server on loopback; a learner steps a fixed batch over its step stream, first alone (the
baseline), then for ``--minutes`` beside clients that misbehave the whole time:

* ``killed``: processes that connect, create a session, stream steps and are SIGKILLed mid-stream
  (0.3 to 3 s after they start; some while still connecting);
* ``bad_input``: wrong shapes, NaN actions, unknown sessions, oversized and malformed sessions,
  undecodable protobuf, garbage on the raw socket, a garbage model and an amplified model
  (empty protobuf nodes) to Evaluate;
* ``never_read``: step streams that keep sending and never read a reply;
* ``storm``: bursts of connections that call once and close, raw connects closed at once, and
  half-open ones that never speak.

Then the learner runs alone again. The report gives the learner's env steps/s alone and beside
the misbehavers, every status code the misbehavers got (INTERNAL means a server fault), and the
server's RSS, open file descriptors, threads and CPU time sampled every 10 s.

The misbehaving processes run at nice 19: in a deployment they are other machines, so their own
Python CPU time should not count against the learner on this 2-core box; the server's work for
them does count. Python (not a Rust example) because it needs no build, drives the real Python
client that learners use, and kills real client processes mid-stream.

    .venv/bin/python tools/soak.py --minutes 30 --out soak.json
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import queue
import random
import re
import signal
import socket
import subprocess
import sys
import threading
import time
from collections import Counter
from pathlib import Path
from typing import Any

import grpc
import numpy as np
from unigait.client.proto import pb, pb_grpc
from unigait.client.tensors import encode

REPO = Path(__file__).resolve().parents[1]
LEARNER_ENVS = 128
#: Server flags of the soak: one env thread, idle sessions (of killed clients) reaped after 30 s,
#: stuck streams given up after 10 s.
SERVER_FLAGS = [
    *("--threads", "1", "--idle-timeout", "30", "--stream-idle-timeout", "10"),
    *("--max-sessions", "64", "--handshake-timeout", "5"),
]
SAMPLE_EVERY_S = 10.0


# --- roles (each runs in its own process) ------------------------------------------------------


class _Stream:
    """A step stream on the raw stub: one request in, one reply read, in order."""

    def __init__(self, stub: Any) -> None:
        self._requests: queue.SimpleQueue[Any] = queue.SimpleQueue()
        self._replies = stub.StepStream(iter(self._requests.get, None))

    def step(self, request: Any) -> Any:
        self._requests.put(request)
        return next(self._replies)

    def close(self) -> None:
        self._requests.put(None)


def _create(stub: Any, num_envs: int, seed: int) -> str:
    config = pb.SessionConfig(num_envs=num_envs, seed=seed)
    return str(stub.CreateSession(pb.CreateSessionRequest(config=config)).session_id)


def learner(address: str, seconds: float) -> None:
    """Step LEARNER_ENVS envs for ``seconds``; print a JSON line per 10 s window.

    It uses the generated stub directly (the same calls as :class:`unigait.client.Session`), so
    the measurement does not move with the client package's Python code.
    """
    channel = grpc.insecure_channel(address, options=[("grpc.max_receive_message_length", -1)])
    stub = pb_grpc.SimulatorStub(channel)
    sid = _create(stub, LEARNER_ENVS, 1)
    actions = np.random.default_rng(0).uniform(-1, 1, (LEARNER_ENVS, 12)).astype(np.float32)
    request = pb.StepRequest(session_id=sid, actions=encode(actions))
    stream = _Stream(stub)
    start = time.monotonic()
    window_start, steps, errors = start, 0, 0
    while time.monotonic() - start < seconds:
        try:
            reply = stream.step(request)
            if len(reply.obs.data) != LEARNER_ENVS * 53 * 4:
                raise RuntimeError(f"a reply of {len(reply.obs.data)} observation bytes")
            steps += 1
        except Exception as err:
            errors += 1
            print(json.dumps({"error": f"{type(err).__name__}: {err}"}), flush=True)
            stream = _Stream(stub)
        now = time.monotonic()
        if now - window_start >= 10.0:
            row = {"t": round(now - start, 2), "dt": now - window_start, "steps": steps}
            print(json.dumps(row), flush=True)
            window_start, steps = now, 0
    print(json.dumps({"done": True, "errors": errors}), flush=True)
    stream.close()
    stub.CloseSession(pb.CloseSessionRequest(session_id=sid))
    channel.close()


def streamer(address: str) -> None:
    """Connect, create a session and stream steps until killed."""
    stub = pb_grpc.SimulatorStub(grpc.insecure_channel(address))
    sid = _create(stub, 16, random.randrange(1 << 30))
    request = pb.StepRequest(session_id=sid, actions=encode(np.zeros((16, 12), np.float32)))
    stream = _Stream(stub)
    while True:
        stream.step(request)
        time.sleep(0.02)


def _code(err: grpc.RpcError) -> str:
    return err.code().name if isinstance(err, grpc.Call) else type(err).__name__


def _amplified_model(nodes: int) -> bytes:
    """ModelProto.graph holding ``nodes`` empty NodeProto entries (2 bytes each on the wire)."""
    body = b"\x0a\x00" * nodes
    n, varint = len(body), bytearray()
    while n >= 0x80:
        varint.append((n & 0x7F) | 0x80)
        n >>= 7
    varint.append(n)
    return b"\x3a" + bytes(varint) + body


def bad_input(address: str, seconds: float) -> None:
    """Send malformed requests of every kind; print the status codes seen."""
    host, port = address.rsplit(":", 1)
    channel = grpc.insecure_channel(address, options=[("grpc.max_send_message_length", 64 << 20)])
    stub = pb_grpc.SimulatorStub(channel)
    raw_step = channel.unary_unary("/unigait.v1.Simulator/Step")
    codes: Counter[str] = Counter()
    session = stub.CreateSession(pb.CreateSessionRequest(config=pb.SessionConfig(num_envs=4)))
    sid = session.session_id
    amplified = _amplified_model(1 << 19)

    def step(actions: np.ndarray, session_id: str = sid) -> Any:
        return stub.Step(pb.StepRequest(session_id=session_id, actions=encode(actions)))

    cases = {
        "actions_11_wide": lambda: step(np.zeros((4, 11), np.float32)),
        "nan_actions": lambda: step(np.full((4, 12), np.nan, np.float32)),
        "actions_5_rows": lambda: step(np.zeros((5, 12), np.float32)),
        "unknown_session": lambda: step(np.zeros((4, 12), np.float32), "no-such-session"),
        "no_actions": lambda: stub.Step(pb.StepRequest(session_id=sid)),
        "1e9_envs": lambda: stub.CreateSession(
            pb.CreateSessionRequest(config=pb.SessionConfig(num_envs=10**9))
        ),
        "bad_toml": lambda: stub.CreateSession(
            pb.CreateSessionRequest(
                config=pb.SessionConfig(num_envs=2, task_overrides_toml="[[[not toml")
            )
        ),
        "deep_toml": lambda: stub.CreateSession(
            pb.CreateSessionRequest(
                config=pb.SessionConfig(num_envs=2, task_overrides_toml="a = " + "[" * 64)
            )
        ),
        # tonic answers bytes that do not decode with INTERNAL (its codec's choice).
        "undecodable": lambda: raw_step(b"\xff\xff\xff\xff\x0f garbage"),
        "garbage_model": lambda: stub.Evaluate(
            pb.EvaluateRequest(policy_onnx=os.urandom(4096), scenario="flat_quad", num_envs=1)
        ),
        "amplified_model": lambda: stub.Evaluate(
            pb.EvaluateRequest(policy_onnx=amplified, scenario="flat_quad", num_envs=1)
        ),
        "unknown_scenario": lambda: stub.Evaluate(
            pb.EvaluateRequest(scenario="no-such-scenario", num_envs=1)
        ),
    }
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        for name, case in cases.items():
            try:
                case()
                codes[f"{name}:OK"] += 1
            except grpc.RpcError as err:
                codes[f"{name}:{_code(err)}"] += 1
            time.sleep(0.05)
        for payload in (b"GET / HTTP/1.1\r\nHost: x\r\n\r\n", os.urandom(512)):
            with socket.create_connection((host, int(port)), timeout=5) as s:
                s.sendall(payload)
                codes["raw_socket"] += 1
        time.sleep(0.2)
    print(json.dumps({"codes": codes}), flush=True)
    channel.close()


def never_read(address: str, seconds: float) -> None:
    """Open step streams that send and never read; drop each after 25 s and start again."""
    channel = grpc.insecure_channel(address)
    stub = pb_grpc.SimulatorStub(channel)
    deadline = time.monotonic() + seconds
    opened = 0
    while time.monotonic() < deadline:
        sid = stub.CreateSession(
            pb.CreateSessionRequest(config=pb.SessionConfig(num_envs=64))
        ).session_id
        request = pb.StepRequest(session_id=sid, actions=encode(np.zeros((64, 12), np.float32)))
        stop = threading.Event()

        def requests(req: Any = request, stop: threading.Event = stop) -> Any:
            while not stop.is_set():
                yield req
                time.sleep(0.02)

        call = stub.StepStream(requests())
        opened += 1
        stop.wait(min(25.0, max(deadline - time.monotonic(), 0.0)))
        stop.set()
        call.cancel()
        with contextlib.suppress(grpc.RpcError):
            stub.CloseSession(pb.CloseSessionRequest(session_id=sid))
    print(json.dumps({"never_read_streams": opened}), flush=True)
    channel.close()


def storm(address: str, seconds: float) -> None:
    """Bursts of connections: call once and close, connect and close, connect and stay silent."""
    host, port = address.rsplit(":", 1)
    counts: Counter[str] = Counter()
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        channels = [grpc.insecure_channel(address) for _ in range(20)]
        for ch in channels:
            try:
                pb_grpc.SimulatorStub(ch).GetServerInfo(pb.GetServerInfoRequest(), timeout=5)
                counts["grpc_ok"] += 1
            except grpc.RpcError as err:
                counts[f"grpc_{_code(err)}"] += 1
            ch.close()
        for _ in range(20):
            with socket.create_connection((host, int(port)), timeout=5):
                counts["tcp_closed"] += 1
        silent = [socket.create_connection((host, int(port)), timeout=5) for _ in range(10)]
        counts["tcp_silent"] += len(silent)
        time.sleep(2.0)
        for s in silent:
            s.close()
    print(json.dumps({"storm": counts}), flush=True)


# --- the orchestrator --------------------------------------------------------------------------


def proc_sample(pid: int) -> dict[str, float]:
    """RSS and peak RSS (KiB), threads, open fds and CPU seconds of process ``pid``."""
    status = Path(f"/proc/{pid}/status").read_text()
    fields = {line.split(":")[0]: line.split(":")[1].split() for line in status.splitlines()}
    stat = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    ticks = os.sysconf("SC_CLK_TCK")
    return {
        "rss_kib": float(fields["VmRSS"][0]),
        "hwm_kib": float(fields["VmHWM"][0]),
        "threads": float(fields["Threads"][0]),
        "fds": float(len(os.listdir(f"/proc/{pid}/fd"))),
        "cpu_s": (int(stat[11]) + int(stat[12])) / ticks,
    }


def spawn_role(role: str, address: str, seconds: float, *, niced: bool) -> subprocess.Popen[str]:
    """Run ``role`` in a new process of this script (at nice 19 if ``niced``)."""
    cmd = [sys.executable, __file__, "--role", role, "--address", address]
    cmd += ["--seconds", str(seconds)]
    return subprocess.Popen(
        cmd,
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        text=True,
        # Only os.nice runs between fork and exec (no lock is taken).
        preexec_fn=(lambda: os.nice(19)) if niced else None,
    )


def run_learner(address: str, seconds: float) -> dict[str, Any]:
    """The learner for ``seconds``; its env steps/s per window, after a 10 s warm-up."""
    proc = spawn_role("learner", address, seconds, niced=False)
    assert proc.stdout is not None
    windows, errors = [], []
    for line in proc.stdout:
        row = json.loads(line)
        if "steps" in row:
            windows.append(row)
        elif "error" in row:
            errors.append(row["error"])
    proc.wait()
    measured = windows[1:] if len(windows) > 1 else windows
    rates = [w["steps"] * LEARNER_ENVS / w["dt"] for w in measured]
    total = sum(w["steps"] for w in measured) * LEARNER_ENVS
    seconds_measured = sum(w["dt"] for w in measured)
    return {
        "env_steps_per_s": total / seconds_measured if seconds_measured else 0.0,
        "worst_window": min(rates) if rates else 0.0,
        "windows": len(rates),
        "window_env_steps_per_s": [round(r, 1) for r in rates],
        "errors": errors,
    }


class Sampler(threading.Thread):
    """Samples the server every SAMPLE_EVERY_S seconds, labelled with the current phase."""

    def __init__(self, pid: int) -> None:
        super().__init__(daemon=True)
        self.pid, self.phase = pid, "start"
        self.rows: list[dict[str, Any]] = []
        self.start_time = time.monotonic()
        self.stopped = threading.Event()

    def sample(self) -> None:
        """Take one sample now."""
        row: dict[str, Any] = {"t_s": round(time.monotonic() - self.start_time, 1)}
        row.update(phase=self.phase, **proc_sample(self.pid))
        self.rows.append(row)

    def run(self) -> None:
        """Sample until stopped."""
        while not self.stopped.wait(SAMPLE_EVERY_S):
            self.sample()


def killer(address: str, until: float, counts: Counter[str]) -> None:
    """Start streamers one after another and SIGKILL each 0.3 to 3 s after its start."""
    rng = random.Random(7)
    while time.monotonic() < until:
        proc = spawn_role("streamer", address, 0, niced=True)
        time.sleep(rng.uniform(0.3, 3.0))
        counts["killed" if proc.poll() is None else "exited_early"] += 1
        proc.send_signal(signal.SIGKILL)
        proc.wait()
        time.sleep(0.2)


def main() -> int:
    """Run a role (internal) or the whole soak."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--role", help=argparse.SUPPRESS)
    ap.add_argument("--address", help=argparse.SUPPRESS)
    ap.add_argument("--seconds", type=float, default=0.0, help=argparse.SUPPRESS)
    ap.add_argument("--minutes", type=float, default=30.0, help="misbehaving phase")
    ap.add_argument("--baseline-minutes", type=float, default=3.0, help="learner alone, before")
    ap.add_argument("--after-minutes", type=float, default=2.0, help="learner alone, after")
    ap.add_argument("--settle-s", type=float, default=45.0, help="wait before the last sample")
    ap.add_argument(
        "--server-bin",
        default=os.environ.get(
            "UNIGAIT_SERVER_BIN", str(REPO / "target" / "release" / "unigait-server")
        ),
    )
    ap.add_argument("--out", type=Path, help="write the full report (JSON) here")
    args = ap.parse_args()
    if args.role:
        roles = {
            "learner": lambda: learner(args.address, args.seconds),
            "streamer": lambda: streamer(args.address),
            "bad_input": lambda: bad_input(args.address, args.seconds),
            "never_read": lambda: never_read(args.address, args.seconds),
            "storm": lambda: storm(args.address, args.seconds),
        }
        roles[args.role]()
        return 0

    server = subprocess.Popen(
        [args.server_bin, "serve", "--addr", "127.0.0.1:0", *SERVER_FLAGS],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env={**os.environ, "RUST_LOG": "warn"},
    )
    assert server.stdout is not None and server.stderr is not None
    address = server.stdout.readline().strip().removeprefix("listening on ")
    log_lines: Counter[str] = Counter()
    log_examples: dict[str, str] = {}

    def drain_log(stream: Any) -> None:
        for line in stream:
            line = re.sub(r"\x1b\[[0-9;]*m", "", line).strip()
            words = line.split()
            level = words[1] if len(words) > 1 else "?"
            log_lines[level] += 1
            if level in ("WARN", "ERROR"):
                log_examples.setdefault(" ".join(words[2:])[:60], line[:300])

    threading.Thread(target=drain_log, args=(server.stderr,), daemon=True).start()
    sampler = Sampler(server.pid)
    sampler.start()
    report: dict[str, Any] = {"server_flags": SERVER_FLAGS, "learner_envs": LEARNER_ENVS}
    try:
        sampler.phase = "baseline"
        sampler.sample()
        report["alone_before"] = run_learner(address, args.baseline_minutes * 60)
        print("alone:", report["alone_before"], flush=True)

        sampler.phase = "soak"
        sampler.sample()
        soak_s = args.minutes * 60
        until = time.monotonic() + soak_s
        others = [spawn_role(r, address, soak_s, niced=True) for r in ("bad_input", "never_read")]
        others.append(spawn_role("storm", address, soak_s, niced=True))
        kills: Counter[str] = Counter()
        killing = threading.Thread(target=killer, args=(address, until, kills), daemon=True)
        killing.start()
        report["beside_misbehavers"] = run_learner(address, soak_s)
        killing.join()
        misbehaved: dict[str, Any] = {"streamers": dict(kills)}
        for proc in others:
            out, _ = proc.communicate(timeout=120)
            for line in out.splitlines():
                misbehaved.update(json.loads(line))
        report["misbehavers"] = misbehaved
        print("beside misbehavers:", report["beside_misbehavers"], flush=True)
        print("misbehavers:", misbehaved, flush=True)

        sampler.phase = "settle"
        time.sleep(args.settle_s)
        sampler.sample()
        sampler.phase = "after"
        report["alone_after"] = run_learner(address, args.after_minutes * 60)
        sampler.sample()
    finally:
        sampler.stopped.set()
        server.send_signal(signal.SIGTERM)
        try:
            server.wait(timeout=30)
        except subprocess.TimeoutExpired:
            server.kill()
    alone = report["alone_before"]["env_steps_per_s"]
    beside = report["beside_misbehavers"]["env_steps_per_s"]
    soak_rows = [r for r in sampler.rows if r["phase"] == "soak"]
    report["summary"] = {
        "learner_alone_env_steps_per_s": round(alone, 1),
        "learner_beside_misbehavers_env_steps_per_s": round(beside, 1),
        "learner_after_env_steps_per_s": round(report["alone_after"]["env_steps_per_s"], 1),
        "beside_over_alone": round(beside / alone, 3) if alone else None,
        "learner_errors": len(report["beside_misbehavers"]["errors"]),
        "server_exit_code": server.returncode,
        "server_log_lines": dict(log_lines),
        "server_log_examples": list(log_examples.values())[:20],
        "rss_mib_soak_min_max": [
            round(min(r["rss_kib"] for r in soak_rows) / 1024, 1),
            round(max(r["rss_kib"] for r in soak_rows) / 1024, 1),
        ],
        "rss_mib_fds_each_5_min": [
            [
                round((r["t_s"] - soak_rows[0]["t_s"]) / 60, 1),
                round(r["rss_kib"] / 1024, 1),
                r["fds"],
            ]
            for r in soak_rows
            if (r["t_s"] - soak_rows[0]["t_s"]) % 300 < SAMPLE_EVERY_S
        ],
        "fds_soak_min_max": [min(r["fds"] for r in soak_rows), max(r["fds"] for r in soak_rows)],
    }
    report["samples"] = sampler.rows
    print(json.dumps(report["summary"], indent=2))
    if args.out:
        args.out.write_text(json.dumps(report, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
