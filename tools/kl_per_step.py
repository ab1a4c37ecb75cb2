"""How far one PPO step moves the policy, against the learning rate: a probe for the adaptive rule.

Collects one rollout with a checkpoint's networks on a recipe stage's task (a local server), then,
from the same networks and the checkpoint's Adam state, takes PPO mini-batch steps at each
learning rate and prints the KL(old || new) over the whole batch after 1 and after 21 steps,
and the actor input's per-dimension scale (what the first layer sees).

    .venv/bin/python tools/kl_per_step.py \
        assets/training/unified_terrain/01_terrain/model_latest.pt --recipe unified_terrain
"""

from __future__ import annotations

import argparse
import copy
import dataclasses
import math

import torch
from unigait.algorithms.ppo import gaussian_kl
from unigait.client import open_session
from unigait.config import session_config
from unigait.env import TorchVecEnv
from unigait.recipes import load_recipe
from unigait.runners import OnPolicyRunner
from unigait.server_process import LocalServer


def batch_kl(runner: OnPolicyRunner, ac: torch.nn.Module) -> float:
    """Mean KL(rollout policy || ac) over every stored sample."""
    s = runner.storage
    obs = s.actor_obs.reshape(-1, s.actor_obs.shape[-1])
    with torch.no_grad():
        dist = ac.distribution(obs)
        kl = gaussian_kl(
            s.mu.reshape(-1, s.mu.shape[-1]),
            s.sigma.reshape(-1, s.sigma.shape[-1]),
            dist.mean,
            dist.stddev,
        )
    return float(kl.mean())


def main() -> None:
    """Print KL per step against the learning rate."""
    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument("checkpoint")
    p.add_argument("--recipe", default="unified_terrain")
    p.add_argument("--stage", type=int, default=-1)
    p.add_argument("--envs", type=int, default=256)
    p.add_argument("--rates", type=float, nargs="+", default=[1e-6, 3e-6, 1e-5, 3e-5, 1e-4])
    args = p.parse_args()
    stage = load_recipe(args.recipe, [f"env.num_envs={args.envs}"]).stages[args.stage]
    cfg = stage.config
    torch.manual_seed(0)
    with LocalServer() as server:
        env = TorchVecEnv(open_session([server.address], session_config(cfg)))
        try:
            runner = OnPolicyRunner(env, cfg, None)
            runner.load(args.checkpoint)
            runner.rollout()
        finally:
            env.close()
    s = runner.storage
    obs = s.actor_obs.reshape(-1, s.actor_obs.shape[-1])
    scale = obs.std(0)
    print(
        f"actor input: {obs.shape[1]} dims; std per dim: median {scale.median():.3f}, "
        f"max {scale.max():.3f} (dim {int(scale.argmax())}), mean |x| {obs.abs().mean():.3f}"
    )
    std = float(runner.actor_critic.std.detach().mean())
    print(f"action std {std:.3f}; KL before any step {batch_kl(runner, runner.actor_critic):.2e}")
    state = copy.deepcopy(runner.ppo.optimizer.state_dict())
    print("lr        KL after 1 step   KL after 21 steps")
    for lr in args.rates:
        ac = copy.deepcopy(runner.actor_critic)
        ppo = copy.copy(runner.ppo)
        ppo.actor_critic = ac
        ppo.optimizer = type(runner.ppo.optimizer)(ac.parameters(), lr=lr)
        ppo.optimizer.load_state_dict(state)
        ppo.cfg = dataclasses.replace(runner.ppo.cfg, schedule="fixed")
        ppo._set_lr(lr)
        after: list[float] = []
        one = ppo.cfg
        ppo.cfg = dataclasses.replace(one, num_learning_epochs=1, num_mini_batches=1)
        ppo.update(s)
        after.append(batch_kl(runner, ac))
        ppo.cfg = dataclasses.replace(one, num_learning_epochs=5, num_mini_batches=4)
        ppo.update(s)  # 20 more mini-batch steps: 21 in all
        after.append(batch_kl(runner, ac))
        print(f"{lr:8.1e}  {after[0]:15.2e}   {after[1]:17.2e}")
    shift = math.sqrt(2 * 0.01 / 12) * std
    print(f"(a KL of 0.01 at std {std:.2f} is a mean shift of {shift:.4f} per action dim)")


if __name__ == "__main__":
    main()
