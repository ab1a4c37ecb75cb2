"""Time one learner update (PPO epochs + estimator epochs) on random data, side by side.

The paper's networks and hyper-parameters (Table III), a rollout of N envs x 24 steps in the
real storage. Variants: torch threads, fused Adam or not. Prints one line per variant (median
of the repeats), e.g.::

    .venv/bin/python tests/data/bench_update.py --envs 512 --repeats 3
"""

from __future__ import annotations

import argparse
import os
import statistics
import time

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import torch
from unigait.algorithms import PPO, EstimatorLearning
from unigait.config import load_config
from unigait.runners import build_networks
from unigait.storage import RolloutStorage


def filled_storage(envs: int, steps: int = 24) -> RolloutStorage:
    storage = RolloutStorage(steps, envs, 159 + 14, 159, 77, 14, 12)
    g = torch.Generator().manual_seed(0)
    for _ in range(steps):
        storage.add(
            torch.randn(envs, 173, generator=g),
            torch.randn(envs, 77, generator=g),
            torch.randn(envs, 14, generator=g),
            torch.randn(envs, 12, generator=g),
            -torch.rand(envs, generator=g) * 10,
            torch.randn(envs, 12, generator=g) * 0.1,
            torch.ones(envs, 12),
            torch.randn(envs, generator=g),
            torch.randn(envs, generator=g) * 0.01,
            torch.rand(envs, generator=g) < 0.01,
        )
    storage.compute_returns(torch.zeros(envs), 0.99, 0.95)
    return storage


def time_update(envs: int, threads: int, fused: bool, repeats: int) -> float:
    torch.set_num_threads(threads)
    torch.manual_seed(0)
    cfg = load_config()
    actor_critic, estimator = build_networks(cfg, 53, 14, 10, 12)
    ppo = PPO(actor_critic, cfg.ppo)
    est = EstimatorLearning(estimator, cfg.estimator)
    if not fused:
        ppo.optimizer = torch.optim.Adam(actor_critic.parameters(), lr=cfg.ppo.learning_rate)
        est.optimizer = torch.optim.Adam(estimator.parameters(), lr=cfg.estimator.learning_rate)
    storage = filled_storage(envs)
    times = []
    for _ in range(repeats + 1):
        start = time.perf_counter()
        ppo.update(storage)
        est.update(storage)
        times.append(time.perf_counter() - start)
    return statistics.median(times[1:])


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument("--envs", type=int, default=512)
    p.add_argument("--repeats", type=int, default=3)
    args = p.parse_args()
    for threads, fused in ((1, False), (1, True), (2, False), (2, True)):
        t = time_update(args.envs, threads, fused, args.repeats)
        samples = args.envs * 24
        print(
            f"envs {args.envs} threads {threads} fused_adam {fused!s:5}: "
            f"update {t:.2f} s ({samples / t:,.0f} samples/s)"
        )


if __name__ == "__main__":
    main()
