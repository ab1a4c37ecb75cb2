"""Throughput of one learner over 1 and 2 Ray server actors, side by side, and what it can feed.

Starts a local Ray instance (``--ray-cpus`` logical CPUs), then for each round trains
``--iterations`` PPO iterations over a pool of N actors (1 CPU and 1 server thread each) for
every N in ``--servers``, the order alternating between rounds so that a machine whose load
drifts (another job) biases neither. Each round also times one server core in process
(``unigait-server bench --threads 1``, same envs). One JSON line per measurement, then a summary:

- ``train_samples_per_s``: env steps the learner trains on per second of wall time (rollout +
  PPO + estimator updates), median of the iterations after the first (warm-up);
- ``rollout_sim_samples_per_s``: env steps per second of the time the learner waited for the
  servers (``time_share/simulation``): what the pool delivered;
- ``learner_bound_samples_per_s``: env steps per second of the learner's own time (inference and
  updates, simulation excluded): the rate with infinitely fast servers;
- ``server_core_steps_per_s``: one server thread in process;
- ``server_cores_one_learner_feeds``: ``learner_bound_samples_per_s / server_core_steps_per_s``,
  the number of server cores one such learner keeps busy (on paper).

Example (a few minutes on 2 cores)::

    UNIGAIT_SERVER_BIN=target/release/unigait-server \\
        .venv/bin/python tests/data/bench_ray.py --envs 512 --iterations 3 --rounds 2
"""

from __future__ import annotations

import argparse
import contextlib
import json
import logging
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import ray
from unigait.config import load_config
from unigait.ray import ServerCredentials, ServerPool, train_with_pool
from unigait.server_process import default_server_bin

TOKEN = "bench-token-0123456789abcdef"


def emit(line: dict[str, Any]) -> None:
    print(json.dumps(line), flush=True)


def train_once(
    servers: int, args: argparse.Namespace, credentials: ServerCredentials | None
) -> dict[str, Any]:
    with tempfile.TemporaryDirectory(prefix="bench-ray-") as log_dir:
        cfg = load_config(
            None,
            [
                f"env.num_envs={args.envs}",
                f"runner.max_iterations={args.iterations}",
                f"runner.num_steps_per_env={args.steps_per_env}",
                f"runner.log_dir={json.dumps(log_dir)}",
                "runner.quiet=true",
                "runner.save_interval=1000000",
                "runner.plot_interval=1000000",
            ],
        )
        started = time.perf_counter()
        with ServerPool(servers, 1, binary=str(args.server_bin), credentials=credentials) as pool:
            pool_start_s = time.perf_counter() - started
            with contextlib.redirect_stdout(sys.stderr):  # stdout: the JSON lines only
                history = train_with_pool(pool, cfg)
    later = history[1:] or history
    samples = args.envs * args.steps_per_env

    def median(f: Any) -> float:
        return round(statistics.median(f(h) for h in later), 1)

    def sim_s(h: dict[str, float]) -> float:
        return h["time_share/simulation"] * h["iteration_time_s"]

    return {
        "train_samples_per_s": median(lambda h: h["env_steps_per_s"]),
        "rollout_sim_samples_per_s": median(lambda h: samples / sim_s(h)),
        "learner_bound_samples_per_s": median(
            lambda h: samples / (h["iteration_time_s"] - sim_s(h))
        ),
        "iteration_time_s": median(lambda h: h["iteration_time_s"]),
        "time_share_simulation": round(
            statistics.median(h["time_share/simulation"] for h in later), 3
        ),
        "pool_start_s": round(pool_start_s, 2),
    }


def server_core(args: argparse.Namespace) -> float:
    cmd = [str(args.server_bin), "bench", "--envs", str(args.envs), "--steps"]
    cmd += [str(args.core_steps), "--threads", "1", "--actions", "random"]
    out = subprocess.run(cmd, check=True, capture_output=True, text=True).stdout
    return float(json.loads(out[out.index("{") :])["env_steps_per_sec"])


def self_signed(directory: Path) -> tuple[Path, Path]:
    cert, key = directory / "cert.pem", directory / "key.pem"
    subprocess.run(
        [
            *("openssl", "req", "-x509", "-newkey", "rsa:2048", "-nodes", "-days", "1"),
            *("-subj", "/CN=localhost", "-addext", "subjectAltName=IP:127.0.0.1"),
            *("-keyout", str(key), "-out", str(cert)),
        ],
        check=True,
        capture_output=True,
    )
    return cert, key


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--envs", type=int, default=512, help="envs of the learner's batch")
    p.add_argument("--iterations", type=int, default=3, help="per run (the first is warm-up)")
    p.add_argument("--steps-per-env", type=int, default=24)
    p.add_argument("--rounds", type=int, default=2, help="rounds over --servers, alternating")
    p.add_argument("--servers", type=int, nargs="+", default=[1, 2])
    p.add_argument("--core-steps", type=int, default=150, help="steps of the in-process bench")
    p.add_argument("--ray-cpus", type=int, default=2, help="logical CPUs of the local Ray")
    p.add_argument("--tls", action="store_true", help="servers with TLS + token (shipped)")
    p.add_argument("--server-bin", type=Path, default=default_server_bin())
    args = p.parse_args()
    logging.basicConfig(level=logging.WARNING)
    os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
    load = os.getloadavg()[0]
    ray.init(num_cpus=args.ray_cpus, include_dashboard=False, log_to_driver=False)
    runs: dict[int, list[dict[str, Any]]] = {n: [] for n in args.servers}
    cores: list[float] = []
    with tempfile.TemporaryDirectory() as tls_dir:
        credentials = None
        if args.tls:
            cert, key = self_signed(Path(tls_dir))
            credentials = ServerCredentials.shipped(cert, key, TOKEN)
        try:
            for r in range(args.rounds):
                order = args.servers if r % 2 == 0 else list(reversed(args.servers))
                for n in order:
                    result = train_once(n, args, credentials)
                    runs[n].append(result)
                    emit({"kind": "train", "round": r, "servers": n, "envs": args.envs, **result})
                cores.append(server_core(args))
                emit(
                    {"kind": "server_core", "round": r, "envs": args.envs, "steps_per_s": cores[-1]}
                )
        finally:
            ray.shutdown()
    core = statistics.median(cores)
    summary: dict[str, Any] = {
        "kind": "summary",
        "envs": args.envs,
        "steps_per_env": args.steps_per_env,
        "iterations": args.iterations,
        "rounds": args.rounds,
        "tls": args.tls,
        "load_avg_1min_at_start": round(load, 2),
        "server_core_steps_per_s": round(core, 1),
    }
    for n, results in runs.items():
        for key in (
            "train_samples_per_s",
            "rollout_sim_samples_per_s",
            "learner_bound_samples_per_s",
        ):
            summary[f"{n}_actors/{key}"] = round(statistics.median(x[key] for x in results), 1)
    first, *rest = args.servers
    for n in rest:
        base = summary[f"{first}_actors/train_samples_per_s"]
        summary[f"train_ratio_{n}_vs_{first}"] = round(
            summary[f"{n}_actors/train_samples_per_s"] / base, 3
        )
    bound = statistics.median(x["learner_bound_samples_per_s"] for rs in runs.values() for x in rs)
    summary["learner_bound_samples_per_s"] = round(bound, 1)
    summary["server_cores_one_learner_feeds"] = round(bound / core, 3)
    emit(summary)
    return 0


if __name__ == "__main__":
    sys.exit(main())
