r"""How far is a checkpoint's policy from the robot's left-right symmetry? Its mirror loss.

The mean square, over the states the policy's mean actions visit on flat ground (with the
task's observation noise) and over the 12 actions, of mu(M x) - M mu(x): the actor's mean at
the mirrored input against the mirror of its mean (decision record 0033). 0 for a symmetric
policy. Also per joint (FL FR RL RR x hip, thigh, calf), e.g.::

    UNIGAIT_SERVER_BIN=target/release/unigait-server .venv/bin/python tools/probe_mirror.py \
        assets/policies/unified_flat/model.pt --mode quad
"""

from __future__ import annotations

import argparse

import torch
from unigait.algorithms.symmetry import ActorMirror
from unigait.client import SessionConfig, open_session
from unigait.env import ObservationHistory, TorchVecEnv
from unigait.export import load_policy
from unigait.server_process import LocalServer


def probe(checkpoint: str, mode: str, envs: int, steps: int, settle: int, seed: int) -> str:
    """One line: the mean mirror loss and its per-joint parts."""
    policy, dims, engine = load_policy(checkpoint)
    biped = {"quad": 0.0, "biped": 1.0}[mode]
    task = f'[physics]\nengine = "{engine}"\n[modes]\nbiped_probability = {biped}\n'
    with LocalServer() as server:
        config = SessionConfig(num_envs=envs, seed=seed, task_overrides_toml=task)
        env = TorchVecEnv(open_session(server.address, config), "cpu")
        mirror = ActorMirror.from_spec(env.spec, 3)
        history = ObservationHistory(envs, 3, dims["obs_dim"], torch.device("cpu"))
        history.reset(env.last.obs)
        per_joint = []
        for t in range(settle + steps):
            with torch.no_grad():
                flat = history.flat.view(envs, -1)
                x = torch.cat([flat, policy.estimator(flat)], dim=-1)
                mean = policy.actor(x)
                if t >= settle:
                    mirrored = policy.actor(mirror.actor_obs(x))
                    per_joint.append((mirrored - mirror.actions(mean)).square().mean(0))
            out = env.step(mean)
            history.push(out.obs, out.dones)
        env.close()
    joints = torch.stack(per_joint).mean(0)
    return f"{mode}: mirror loss {joints.mean():.3f}; per joint " + " ".join(
        f"{v:.2f}" for v in joints.tolist()
    )


def main() -> None:
    """Parse the command line and print one line per mode."""
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    p.add_argument("checkpoint", help="model_*.pt")
    p.add_argument("--mode", choices=["quad", "biped"], nargs="+", default=["quad", "biped"])
    p.add_argument("--envs", type=int, default=256)
    p.add_argument("--steps", type=int, default=200, help="policy steps measured")
    p.add_argument("--settle", type=int, default=100, help="steps before measuring")
    p.add_argument("--seed", type=int, default=3)
    a = p.parse_args()
    for mode in a.mode:
        print(probe(a.checkpoint, mode, a.envs, a.steps, a.settle, a.seed), flush=True)


if __name__ == "__main__":
    main()
