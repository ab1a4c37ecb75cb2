r"""Time one learner update at a recipe stage's sizes, on a real rollout, part by part.

Opens a local server with the stage's config on flat ground, collects one rollout with the
stage's networks (from ``--checkpoint``, else fresh), then times PPO's epochs, the estimator's
epochs and PPO's epochs without the mirror loss on that stored rollout, and prints the update's
floating-point rate. Pause training first (SIGSTOP): the figures are the CPU's. E.g.::

    .venv/bin/python tools/bench_stage_update.py --recipe unified_terrain \
        --checkpoint assets/training/unified_terrain/16_paper_friction/model_latest.pt
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import time
from collections.abc import Callable

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import torch
from unigait.client import open_session
from unigait.env import TorchVecEnv
from unigait.recipes import load_recipe
from unigait.runners.on_policy_runner import OnPolicyRunner
from unigait.runners.training import session_config
from unigait.server_process import LocalServer


def fastest(fn: Callable[[], object], repeats: int) -> float:
    """The shortest of ``repeats`` wall times of ``fn`` (s)."""
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return min(times)


def training_flop(layers: list[torch.nn.Linear]) -> int:
    """Floating-point operations of one sample's forward and backward pass through ``layers``.

    Each layer's multiply-adds (2 flops each) run three times, forward, weight gradient and
    input gradient, but the first layer's input gradient, which nothing needs.
    """
    macs = [layer.in_features * layer.out_features for layer in layers]
    return 2 * (3 * sum(macs) - macs[0])


def linears(module: torch.nn.Module) -> list[torch.nn.Linear]:
    """The linear layers of ``module``, in order."""
    return [m for m in module.modules() if isinstance(m, torch.nn.Linear)]


def main() -> None:
    """Parse the command line, collect a rollout, print the timings."""
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    p.add_argument("--recipe", default="unified_terrain")
    p.add_argument("--stage", help="stage name (default: the last)")
    p.add_argument("--checkpoint", help="networks to start from (default: fresh)")
    p.add_argument("--repeats", type=int, default=3)
    a = p.parse_args()
    stages = load_recipe(a.recipe).stages
    stage = next(s for s in stages if s.name == a.stage) if a.stage else stages[-1]
    cfg = stage.config
    cfg = dataclasses.replace(cfg, env=dataclasses.replace(cfg.env, terrain="flat"))
    with LocalServer() as server:
        env = TorchVecEnv(open_session([server.address], session_config(cfg, [])), "cpu")
        try:
            runner = OnPolicyRunner(env, cfg, None)
            if a.checkpoint:
                runner.load_weights(a.checkpoint)
            torch.set_num_threads(cfg.runner.torch_threads)
            runner.learn(1)  # one real rollout in the storage
            torch.set_num_threads(cfg.runner.update_threads or cfg.runner.torch_threads)
            ppo, estimator = runner.ppo, runner.estimator_learning
            t_ppo = fastest(lambda: ppo.update(runner.storage), a.repeats)
            t_est = fastest(lambda: estimator.update(runner.storage), a.repeats)
            mirror, ppo.mirror = ppo.mirror, None
            t_plain = fastest(lambda: ppo.update(runner.storage), a.repeats)
            ppo.mirror = mirror
        finally:
            env.close()
    samples = env.num_envs * cfg.runner.num_steps_per_env
    ac = runner.actor_critic
    actor, critic = training_flop(linears(ac.actor)), training_flop(linears(ac.critic))
    passes = samples * cfg.ppo.num_learning_epochs  # every sample once per epoch
    ppo_flop = passes * (actor + critic)
    mirror_flop = passes * actor if mirror else 0.0
    est_flop = samples * cfg.estimator.num_epochs * training_flop(linears(runner.estimator))
    print(f"{a.recipe}:{stage.name}, {env.num_envs} envs x {cfg.runner.num_steps_per_env} steps")
    print(f"PPO epochs: {t_ppo:.3f} s ({(ppo_flop + mirror_flop) / t_ppo / 1e9:.0f} GFLOP/s)")
    print(f"  without the mirror loss: {t_plain:.3f} s ({ppo_flop / t_plain / 1e9:.0f} GFLOP/s)")
    print(f"estimator epochs: {t_est:.3f} s ({est_flop / t_est / 1e9:.0f} GFLOP/s)")
    print(f"update: {t_ppo + t_est:.3f} s (fastest of {a.repeats} each)")


if __name__ == "__main__":
    main()
