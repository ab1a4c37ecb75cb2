r"""Does a checkpoint's quad turn when told to? Its yaw rate under fixed yaw-rate commands.

Every env walks on four legs for the whole episode with one fixed command (vx, 0, wz) per run,
no observation noise, no random episode start. After a settling time the probe reports the mean
yaw rate (the base's angular velocity about its z axis, which on four legs is the vertical) and
the mean absolute error against wz: the gain of the turn, and, at wz = 0, how far the yaw swings
with each stride, e.g.::

    UNIGAIT_SERVER_BIN=target/release/unigait-server .venv/bin/python tools/probe_quad_turn.py \
        assets/policies/unified_flat/model.pt --wz -0.8 0 0.8
"""

from __future__ import annotations

import argparse

import torch
from unigait.client import SessionConfig, open_session
from unigait.env import ObservationHistory, TorchVecEnv
from unigait.export import load_policy
from unigait.mujoco.observation import OBS_SCALE
from unigait.server_process import LocalServer


def overrides(vx: float, wz: float, engine: str) -> str:
    """Quad mode only, one command for the whole episode, noise-free observations."""
    return (
        f'[physics]\nengine = "{engine}"\n'
        "[modes]\nbiped_probability = 0.0\n[noise]\nenabled = false\n"
        "[env]\nrandom_initial_episode_step = false\n"
        "[commands]\nresampling_time_s = 60.0\nzero_below = 0.0\n"
        f"quad = {{ vx = [{vx}, {vx}], vy = [0.0, 0.0], wz = [{wz}, {wz}] }}\n"
    )


def main() -> None:
    """Parse the command line and print one line per --wz."""
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    p.add_argument("checkpoint", help="model_*.pt")
    p.add_argument("--vx", type=float, default=0.5, help="forward command of every run (m/s)")
    p.add_argument("--wz", type=float, nargs="+", default=[-0.8, 0.0, 0.8])
    p.add_argument("--envs", type=int, default=32)
    p.add_argument("--steps", type=int, default=300, help="policy steps (50 per second)")
    p.add_argument("--settle", type=int, default=100, help="steps before measuring")
    p.add_argument("--seed", type=int, default=5)
    a = p.parse_args()
    policy, dims, engine = load_policy(a.checkpoint)
    with LocalServer() as server:
        for wz in a.wz:
            config = SessionConfig(
                num_envs=a.envs, seed=a.seed, task_overrides_toml=overrides(a.vx, wz, engine)
            )
            env = TorchVecEnv(open_session(server.address, config), "cpu")
            omega = env.spec.obs.slice("omega")
            yaw_scale = float(OBS_SCALE[omega][2])  # o_t holds omega times its scale
            history = ObservationHistory(a.envs, 3, dims["obs_dim"], torch.device("cpu"))
            history.reset(env.last.obs)
            rates = []
            for t in range(a.steps):
                with torch.no_grad():
                    actions = policy(history.flat.view(a.envs, 3, -1))
                out = env.step(actions)
                history.push(out.obs, out.dones)
                if t >= a.settle:
                    rates.append(out.obs[:, omega][:, 2] / yaw_scale)
            env.close()
            w = torch.stack(rates)
            print(
                f"vx {a.vx:+.2f} wz {wz:+.2f}: yaw rate {w.mean():+.3f} rad/s, "
                f"mean |error| {(w - wz).abs().mean():.3f}",
                flush=True,
            )


if __name__ == "__main__":
    main()
