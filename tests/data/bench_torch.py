"""Time torch on the paper-sized policy (the network ``make_test_policy.py --paper`` writes).

Same structure and sizes as the ONNX graph tract runs: flatten [B, 3, 53] -> estimator
[256, 128] -> 14, actor on concat(history, estimate) [512, 256, 128] -> 12, ELU. Prints one JSON
line per thread count: the median time per batched call (ms) and per env (us)::

    .venv/bin/python tests/data/bench_torch.py --batch 4096
"""

from __future__ import annotations

import argparse
import json
import time

import torch
from torch import nn


def mlp(sizes: list[int]) -> nn.Sequential:
    layers: list[nn.Module] = []
    for i in range(len(sizes) - 1):
        layers.append(nn.Linear(sizes[i], sizes[i + 1]))
        if i + 2 < len(sizes):
            layers.append(nn.ELU())
    return nn.Sequential(*layers)


class Policy(nn.Module):
    def __init__(self) -> None:
        super().__init__()
        self.estimator = mlp([159, 256, 128, 14])
        self.actor = mlp([173, 512, 256, 128, 12])

    def forward(self, history: torch.Tensor) -> torch.Tensor:
        flat = history.flatten(1)
        return self.actor(torch.cat([flat, self.estimator(flat)], dim=1))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--batch", type=int, default=4096)
    parser.add_argument("--iterations", type=int, default=20)
    parser.add_argument("--threads", type=int, nargs="+", default=[1, 2])
    args = parser.parse_args()
    torch.manual_seed(0)
    policy = Policy().eval()
    x = torch.rand(args.batch, 3, 53) * 2 - 1
    for threads in args.threads:
        torch.set_num_threads(threads)
        times = []
        with torch.inference_mode():
            for _ in range(3):
                policy(x)
            for _ in range(args.iterations):
                t = time.perf_counter()
                policy(x)
                times.append(time.perf_counter() - t)
        times.sort()
        median = times[len(times) // 2]
        print(
            json.dumps(
                {
                    "engine": "torch",
                    "version": torch.__version__,
                    "batch": args.batch,
                    "threads": threads,
                    "median_ms": round(median * 1e3, 3),
                    "min_ms": round(times[0] * 1e3, 3),
                    "per_env_us": round(median * 1e6 / args.batch, 3),
                }
            )
        )


if __name__ == "__main__":
    main()
