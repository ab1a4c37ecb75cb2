"""Time one learner update (PPO epochs + estimator epochs) on random data, before vs after.

The long run's shapes by default: 1024 envs x 24 steps, actor and critic [256, 128, 64],
estimator [256, 128], PPO 5 epochs x 4 mini-batches, estimator 5 epochs of 768 (160 steps),
on the runner's 2 update threads. Variants (and thread counts) run interleaved in one process
(the order rotates each repetition) so that another process on the CPU slows them alike:

- ``before``: the code as it was: torch's ELU (its ``expm1`` kernel) and nine gathers per
  mini-batch from separate tensors (kept below as :class:`PerMiniBatchGathers`);
- ``elu_only`` / ``gather_only``: one of the two changes;
- ``after``: the package as it is.

Every variant runs the same number of gradient steps on the same data. Prints the median over
the repetitions of PPO, estimator and total seconds per update, and (``--inference``) the
rollout's no-grad forwards (estimator, actor, critic, 24 steps) per iteration. ``--check``
times nothing: it runs one update of each variant from the same seed and prints how far the
parameters end apart (the gathers change nothing; the ELU moves them by rounding)::

    .venv/bin/python tests/data/bench_update.py --repeats 7
    .venv/bin/python tests/data/bench_update.py --envs 4096 --paper-dims --threads 1 2
    .venv/bin/python tests/data/bench_update.py --check --envs 256 \\
        --variants before gather_only elu_only after
"""

from __future__ import annotations

import argparse
import os
import statistics
import time
from collections.abc import Iterator

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import torch
from torch import nn
from unigait.algorithms import PPO, EstimatorLearning
from unigait.config import apply, load_config
from unigait.modules import ActorCritic, Estimator
from unigait.modules.mlp import ELU
from unigait.runners import build_networks
from unigait.storage import RolloutStorage
from unigait.storage.rollout_storage import MiniBatch

STEPS = 24
FIELDS = (
    "actor_obs",
    "critic_obs",
    "actions",
    "log_prob",
    "mu",
    "sigma",
    "values",
    "advantages",
    "returns",
)


class PerMiniBatchGathers(RolloutStorage):
    """The storage's iterators as they were: each mini-batch gathered field by field.

    The fields are contiguous copies (as the separate tensors were), made once, untimed.
    """

    def freeze(self) -> None:
        """Take the contiguous copies (call after the rollout is stored)."""
        self.flat = {name: getattr(self, name).flatten(0, 1).contiguous() for name in FIELDS}
        self.flat_history = self.actor_obs[..., : self.history_dim].flatten(0, 1).contiguous()
        self.flat_labels = self.labels.flatten(0, 1).contiguous()

    def mini_batches(self, num_mini_batches: int, num_epochs: int) -> Iterator[MiniBatch]:
        """Nine index gathers per mini-batch."""
        n = self.num_steps * self.num_envs
        size = n // num_mini_batches
        flat = self.flat
        for _ in range(num_epochs):
            perm = torch.randperm(n)
            for i in range(num_mini_batches):
                idx = perm[i * size : (i + 1) * size]
                yield MiniBatch(
                    actor_obs=flat["actor_obs"][idx],
                    critic_obs=flat["critic_obs"][idx],
                    actions=flat["actions"][idx],
                    old_log_prob=flat["log_prob"][idx],
                    old_mu=flat["mu"][idx],
                    old_sigma=flat["sigma"][idx],
                    old_values=flat["values"][idx],
                    advantages=flat["advantages"][idx],
                    returns=flat["returns"][idx],
                )

    def estimator_batches(
        self, batch_size: int, num_epochs: int
    ) -> Iterator[tuple[torch.Tensor, torch.Tensor]]:
        """Two index gathers per batch."""
        history, labels = self.flat_history, self.flat_labels
        n = history.shape[0]
        for _ in range(num_epochs):
            perm = torch.randperm(n)
            for start in range(0, n - batch_size + 1 if n >= batch_size else 1, batch_size):
                idx = perm[start : start + batch_size]
                yield history[idx], labels[idx]


def fill(storage: RolloutStorage, envs: int) -> None:
    """A rollout of random values (fixed seed), returns and normalised advantages."""
    g = torch.Generator().manual_seed(0)
    for _ in range(STEPS):
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


def filled_storage(envs: int, per_mini_batch_gathers: bool = False) -> RolloutStorage:
    """A filled storage of the real sizes (actor 173, history 159, critic 77, labels 14)."""
    cls = PerMiniBatchGathers if per_mini_batch_gathers else RolloutStorage
    storage = cls(STEPS, envs, 159 + 14, 159, 77, 14, 12)
    fill(storage, envs)
    if isinstance(storage, PerMiniBatchGathers):
        storage.freeze()
    return storage


def use_torch_elu(module: nn.Module) -> None:
    """Swap every ELU of ``module`` for torch's own (the code before)."""
    for name, child in module.named_children():
        if isinstance(child, ELU):
            setattr(module, name, nn.ELU())
        else:
            use_torch_elu(child)


class Variant:
    """Learners and storage of one variant, built from the same seed."""

    def __init__(self, args: argparse.Namespace, torch_elu: bool, old_gathers: bool) -> None:
        cfg = load_config()
        if not args.paper_dims:
            dims = [256, 128, 64]
            cfg = apply(cfg, {"policy": {"actor_hidden_dims": dims, "critic_hidden_dims": dims}})
        torch.manual_seed(0)
        self.actor_critic, self.estimator = build_networks(cfg, 53, 14, 10, 12)
        if torch_elu:
            use_torch_elu(self.actor_critic)
            use_torch_elu(self.estimator)
        self.ppo = PPO(self.actor_critic, cfg.ppo)
        self.est = EstimatorLearning(self.estimator, cfg.estimator)
        self.storage = filled_storage(args.envs, old_gathers)
        self.envs = args.envs

    def update(self) -> tuple[float, float]:
        """Seconds of PPO's and of the estimator's epochs."""
        start = time.perf_counter()
        self.ppo.update(self.storage)
        mid = time.perf_counter()
        self.est.update(self.storage)
        return mid - start, time.perf_counter() - mid

    def inference(self) -> float:
        """Seconds of a rollout's no-grad forwards (estimator, actor, critic; 24 steps)."""
        history = torch.randn(self.envs, 159)
        critic_obs = torch.randn(self.envs, 77)
        ac: ActorCritic = self.actor_critic
        est: Estimator = self.estimator
        start = time.perf_counter()
        with torch.no_grad():
            for _ in range(STEPS):
                actor_obs = torch.cat([history, est(history)], dim=-1)
                ac.act(actor_obs)
                ac.value(critic_obs)
        return time.perf_counter() - start


VARIANTS = {
    "before": (True, True),
    "elu_only": (False, True),
    "gather_only": (True, False),
    "after": (False, False),
}


def check(args: argparse.Namespace) -> None:
    """Print how far each variant's parameters end from the first's after one update."""
    torch.set_num_threads(args.threads[0])
    params = {}
    for name in args.variants:
        v = Variant(args, *VARIANTS[name])
        torch.manual_seed(123)  # the same permutations for every variant
        stats = v.ppo.update(v.storage) | v.est.update(v.storage)
        flat = [
            torch.cat([p.detach().flatten() for p in m.parameters()])
            for m in (v.actor_critic, v.estimator)
        ]
        params[name] = flat
        first = params[args.variants[0]]
        print(
            f"{name:11s}: max |param - {args.variants[0]}'s| actor-critic "
            f"{(flat[0] - first[0]).abs().max().item():.2e}, estimator "
            f"{(flat[1] - first[1]).abs().max().item():.2e}; "
            + ", ".join(f"{k} {stats[k]:.6g}" for k in ("kl", "value_loss", "estimator_loss"))
        )


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument("--envs", type=int, default=1024)
    p.add_argument("--repeats", type=int, default=5)
    p.add_argument("--threads", type=int, nargs="+", default=[2])
    p.add_argument("--variants", nargs="+", choices=list(VARIANTS), default=["before", "after"])
    p.add_argument("--paper-dims", action="store_true", help="actor/critic [512, 256, 128]")
    p.add_argument("--inference", action="store_true", help="also time the rollout's forwards")
    p.add_argument(
        "--check",
        action="store_true",
        help="no timing: one update of each variant from the same seed, parameters compared",
    )
    args = p.parse_args()
    if args.check:
        check(args)
        return
    dims = "[512, 256, 128]" if args.paper_dims else "[256, 128, 64]"
    print(
        f"envs {args.envs} x {STEPS} steps, actor/critic {dims}, {args.repeats} repeats "
        f"(+1 warm-up), median; torch {torch.__version__}, "
        f"cpu capability {torch.backends.cpu.get_cpu_capability()}"
    )
    keys = [(t, name) for t in args.threads for name in args.variants]
    variants = {key: Variant(args, *VARIANTS[key[1]]) for key in keys}
    times: dict[tuple[int, str], list[tuple[float, float, float]]] = {key: [] for key in keys}
    for rep in range(args.repeats + 1):
        # Rotate the order so that no variant always runs first (or right after another).
        for threads, name in keys[rep % len(keys) :] + keys[: rep % len(keys)]:
            torch.set_num_threads(threads)
            v = variants[threads, name]
            ppo_s, est_s = v.update()
            inf_s = v.inference() if args.inference else 0.0
            if rep > 0:
                times[threads, name].append((ppo_s, est_s, inf_s))
    base = statistics.median(a + b for a, b, _ in times[keys[0]])
    for (threads, name), rows in times.items():
        ppo_s = statistics.median(r[0] for r in rows)
        est_s = statistics.median(r[1] for r in rows)
        total = statistics.median(r[0] + r[1] for r in rows)
        line = (
            f"threads {threads} {name:11s}: update {total * 1e3:7.0f} ms "
            f"(PPO {ppo_s * 1e3:6.0f} ms, estimator {est_s * 1e3:6.0f} ms) "
            f"x{base / total:4.2f} of the first"
        )
        if args.inference:
            line += f"; rollout forwards {statistics.median(r[2] for r in rows) * 1e3:5.0f} ms"
        print(line, flush=True)


if __name__ == "__main__":
    main()
