"""Time torch on the paper-sized policy (the network ``make_test_policy.py --paper`` writes).

Same structure and sizes as the ONNX graph tract runs: flatten [B, 3, 53] -> estimator
[256, 128] -> 14, actor on concat(history, estimate) [512, 256, 128] -> 12, ELU. With ``--onnx``
the weights are read from that file, and the inputs are those of ``bench_policy`` (the
``history_inputs`` formula), so both engines run the very same network on the very same data
(compare the ``checksum`` fields). Prints one JSON line per thread count: the median wall time per
batched call (ms), per env (us), and the median CPU time of the calling thread (ms, comparable at
one thread; with more, torch's worker threads are not counted)::

    .venv/bin/python tests/data/make_test_policy.py --paper /tmp/paper_policy.onnx
    .venv/bin/python tests/data/bench_torch.py --onnx /tmp/paper_policy.onnx --batch 4096 \
        --threads 1
"""

from __future__ import annotations

import argparse
import json
import time

import torch
from torch import nn

HISTORY, OBS_DIM = 3, 53


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


def load_onnx_weights(policy: Policy, path: str) -> None:
    """Copy the initializers ``{estimator,actor}.{i}.{weight,bias}`` of ``make_test_policy.py``.

    Its layer ``i`` is the ``2 * i``-th module of the ``nn.Sequential`` (an ELU sits between
    linears); the weights are ``[out, in]`` there as in torch (Gemm with ``transB=1``).
    """
    import onnx
    from onnx import numpy_helper

    inits = {t.name: numpy_helper.to_array(t) for t in onnx.load(path).graph.initializer}
    state = {}
    for name, value in inits.items():
        prefix, layer, kind = name.split(".")
        state[f"{prefix}.{2 * int(layer)}.{kind}"] = torch.from_numpy(value.copy())
    policy.load_state_dict(state, strict=True)


def history_inputs(batch: int) -> torch.Tensor:
    """``x[b, k] = ((b * 53 + k * 17) % 101) / 50 - 1``, as ``bench_policy`` and the tests."""
    b = torch.arange(batch, dtype=torch.int64)[:, None]
    k = torch.arange(HISTORY * OBS_DIM, dtype=torch.int64)[None, :]
    x = ((b * 53 + k * 17) % 101).to(torch.float32) / 50.0 - 1.0
    return x.reshape(batch, HISTORY, OBS_DIM)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--batch", type=int, default=4096)
    parser.add_argument("--iterations", type=int, default=20)
    parser.add_argument("--threads", type=int, nargs="+", default=[1, 2])
    parser.add_argument(
        "--onnx", help="take the weights from this ONNX file (make_test_policy.py --paper)"
    )
    args = parser.parse_args()
    torch.manual_seed(0)
    policy = Policy().eval()
    if args.onnx:
        load_onnx_weights(policy, args.onnx)
    x = history_inputs(args.batch)
    for threads in args.threads:
        torch.set_num_threads(threads)
        assert torch.get_num_threads() == threads, torch.get_num_threads()
        wall, cpu = [], []
        with torch.inference_mode():
            for _ in range(3):
                out = policy(x)
            for _ in range(args.iterations):
                t, c = time.perf_counter(), time.thread_time()
                out = policy(x)
                cpu.append(time.thread_time() - c)
                wall.append(time.perf_counter() - t)
        wall.sort()
        cpu.sort()
        median = wall[len(wall) // 2]
        print(
            json.dumps(
                {
                    "engine": "torch",
                    "version": torch.__version__,
                    "batch": args.batch,
                    "threads": threads,
                    "weights": args.onnx or "random (no --onnx)",
                    "median_ms": round(median * 1e3, 3),
                    "min_ms": round(wall[0] * 1e3, 3),
                    "cpu_ms": round(cpu[len(cpu) // 2] * 1e3, 3),
                    "per_env_us": round(median * 1e6 / args.batch, 3),
                    "checksum": round(float(out.double().sum()), 6),
                }
            )
        )


if __name__ == "__main__":
    main()
