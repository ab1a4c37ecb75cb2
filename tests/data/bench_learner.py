"""Env steps/s of a whole training iteration (rollout + PPO + estimator), side by side.

Runs ``python -m unigait train`` for a few iterations per (envs, thread setting) on a local
server, variants taking turns, and prints one JSON line per run with the median env steps/s of
the iterations after the first (which pays for warm-up). Thread settings:

- ``1/1``: one torch thread throughout (the learner before this round);
- ``1/2``: one thread while the server steps, two during the update;
- ``2/2``: two threads for inference too (the server is idle while the learner infers).

Networks (actor and critic hidden layers; the estimator stays [256, 128]): ``table3``
[512, 256, 128] (the paper's) and ``half`` [256, 128, 64].

Example (training paused or not running)::

    .venv/bin/python tests/data/bench_learner.py --envs 256 512 1024 --iterations 4
    .venv/bin/python tests/data/bench_learner.py --envs 512 --variants 1/2 --networks table3 half
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

VARIANTS = {"1/1": (1, 1), "1/2": (1, 2), "2/2": (2, 2)}
NETWORKS = {"table3": [512, 256, 128], "half": [256, 128, 64]}


def run(envs: int, variant: str, network: str, iterations: int, seed: int) -> dict[str, object]:
    rollout_threads, update_threads = VARIANTS[variant]
    with tempfile.TemporaryDirectory() as log_dir:
        cmd = [
            sys.executable,
            "-m",
            "unigait",
            "train",
            "--num-envs",
            str(envs),
            "--iterations",
            str(iterations),
            "--seed",
            str(seed),
            "--log-dir",
            log_dir,
            "--quiet",
            "--set",
            f"runner.torch_threads={rollout_threads}",
            "--set",
            f"runner.update_threads={update_threads}",
            "--set",
            "runner.save_interval=1000000",
            "--set",
            "runner.plot_interval=1000000",
            "--set",
            f"policy.actor_hidden_dims={NETWORKS[network]}",
            "--set",
            f"policy.critic_hidden_dims={NETWORKS[network]}",
        ]
        subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL, env=os.environ.copy())
        with (Path(log_dir) / "progress.csv").open() as f:
            rows = list(csv.DictReader(f))
    later = rows[1:] or rows
    return {
        "envs": envs,
        "threads_rollout_update": variant,
        "network": network,
        "env_steps_per_sec": round(statistics.median(float(r["env_steps_per_s"]) for r in later)),
        "time_share_update": round(
            statistics.median(float(r["time_share/update"]) for r in later), 3
        ),
        "iterations_timed": len(later),
    }


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument("--envs", type=int, nargs="+", default=[256, 512, 1024])
    p.add_argument("--variants", nargs="+", default=list(VARIANTS), choices=list(VARIANTS))
    p.add_argument("--networks", nargs="+", default=["table3"], choices=list(NETWORKS))
    p.add_argument("--iterations", type=int, default=4)
    p.add_argument("--seed", type=int, default=1)
    args = p.parse_args()
    for envs in args.envs:
        for variant in args.variants:
            for network in args.networks:
                row = run(envs, variant, network, args.iterations, args.seed)
                print(json.dumps(row), flush=True)


if __name__ == "__main__":
    main()
