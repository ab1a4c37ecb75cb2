"""Does a checkpoint's biped walk where it is told to? Forward speed under fixed commands.

Every env is in biped mode for the whole episode (no mode switch), with one fixed command
(vx, vy, wz) per run, no observation noise, no random episode start. After a settling time the
probe measures, over the surviving envs, the base velocity in the heading frame (the frame the
commands and the tracking reward use: x along the horizontal projection of the body's x axis
plus its z axis, so the back's direction when standing on the front legs), the share of steps
above the upright threshold (1.4 rad), the share with the head on the ground and each front
foot's contact share, e.g.::

    UNIGAIT_SERVER_BIN=target/release/unigait-server \\
        .venv/bin/python tests/data/probe_biped_walk.py assets/policies/unified_flat/model.pt

A walking biped follows the sign and roughly the size of vx; one that stands in place moves at
a few cm/s whatever it is told. The tracking error |v* - v| (what `unigait eval` averages) is
split into the error of each env's mean velocity over the measured window (how far off its
walk is) and what the step-to-step sway adds on top.
"""

from __future__ import annotations

import argparse

import torch
from unigait.client import SessionConfig, open_session
from unigait.env import ObservationHistory, TorchVecEnv
from unigait.export import load_policy
from unigait.server_process import LocalServer

UPRIGHT_PITCH = 1.4


def overrides(vx: float, vy: float, wz: float) -> str:
    """Biped mode only, one command for the whole episode, noise-free observations."""
    return (
        "[modes]\nbiped_probability = 1.0\nresampling_time_s = 60.0\n"
        "[env]\nrandom_initial_episode_step = false\n"
        "[noise]\nenabled = false\n"
        f"[commands]\nresampling_time_s = 60.0\nzero_below = 0.0\n"
        f"biped = {{ vx = [{vx}, {vx}], vy = [{vy}, {vy}], wz = [{wz}, {wz}] }}\n"
    )


def heading_velocity(obs: torch.Tensor, base_linvel: torch.Tensor) -> torch.Tensor:
    """[N, 2] velocity (forward, left) in the heading frame from o_t and the velocity label.

    o_t's orientation part is (gravity y, Euler pitch, gravity z) in the base frame; gravity x
    is sin(pitch). The heading axis is (1, 0, 1) of the base frame made horizontal.
    """
    pitch = obs[:, 4]
    gravity = torch.stack([torch.sin(pitch), obs[:, 3], obs[:, 5]], dim=1)
    gravity = gravity / gravity.norm(dim=1, keepdim=True)
    forward = torch.tensor([1.0, 0.0, 1.0]).expand_as(gravity)
    forward = forward - (forward * gravity).sum(1, keepdim=True) * gravity
    forward = forward / forward.norm(dim=1, keepdim=True)
    left = torch.cross(-gravity, forward, dim=1)
    return torch.stack(
        [(base_linvel * forward).sum(1), (base_linvel * left).sum(1)],
        dim=1,
    )


def probe(
    checkpoint: str,
    command: tuple[float, float, float],
    envs: int,
    steps: int,
    settle: int,
    seed: int,
) -> str:
    vx, vy, wz = command
    policy, dims = load_policy(checkpoint)
    with LocalServer() as server:
        config = SessionConfig(num_envs=envs, seed=seed, task_overrides_toml=overrides(vx, vy, wz))
        env = TorchVecEnv(open_session(server.address, config), "cpu")
        history = ObservationHistory(envs, 3, dims["obs_dim"], torch.device("cpu"))
        history.reset(env.last.obs)
        alive = torch.ones(envs, dtype=torch.bool)
        velocity, upright, head, front, error = [], [], [], [], []
        target = torch.tensor([vx, vy])
        velocity_sum = torch.zeros(envs, 2)
        counted = torch.zeros(envs)
        for t in range(steps):
            with torch.no_grad():
                actions = policy(history.flat.view(envs, 3, -1))
            out = env.step(actions)
            history.push(out.obs, out.dones)
            alive &= ~out.terminated
            if t < settle:
                continue
            m = alive & ~out.dones
            v_now = heading_velocity(out.obs[m], out.labels[m, 0:3])
            velocity.append(v_now)
            error.append((v_now - target).norm(dim=1))
            velocity_sum[m] += v_now
            counted[m] += 1
            upright.append(out.obs[m, 4] > UPRIGHT_PITCH)
            head.append(out.head_contact[m].bool())
            front.append(out.labels[m, 3:5] > 0.5)
        env.close()
    v = torch.cat(velocity)
    measured = counted > 0
    env_mean = velocity_sum[measured] / counted[measured].unsqueeze(1)
    return (
        f"vx {vx:+.2f} vy {vy:+.2f} wz {wz:+.2f}: "
        f"forward {v[:, 0].mean():+.3f} m/s, left {v[:, 1].mean():+.3f} m/s, "
        f"|v| {v.norm(dim=1).mean():.3f} m/s, error {torch.cat(error).mean():.3f} m/s "
        f"(of the envs' mean velocity {(env_mean - target).norm(dim=1).mean():.3f}), "
        f"upright {torch.cat(upright).float().mean():.2f}, "
        f"head down {torch.cat(head).float().mean():.2f}, front feet down "
        + "/".join(f"{x:.2f}" for x in torch.cat(front).float().mean(0).tolist())
        + f", alive {int(alive.sum())}/{envs}"
    )


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    p.add_argument("checkpoint", help="model_*.pt")
    p.add_argument("--vx", type=float, nargs="+", default=[-0.4, 0.0, 0.4])
    p.add_argument("--vy", type=float, default=0.0, help="lateral command of every run")
    p.add_argument("--wz", type=float, default=0.0, help="yaw-rate command of every run")
    p.add_argument("--envs", type=int, default=32)
    p.add_argument("--steps", type=int, default=400, help="policy steps (50 per second)")
    p.add_argument("--settle", type=int, default=150, help="steps before measuring")
    p.add_argument("--seed", type=int, default=5)
    a = p.parse_args()
    for vx in a.vx:
        print(probe(a.checkpoint, (vx, a.vy, a.wz), a.envs, a.steps, a.settle, a.seed), flush=True)


if __name__ == "__main__":
    main()
