r"""Does a checkpoint's biped walk where it is told to? Forward speed under fixed commands.

Every env is in biped mode for the whole episode (no mode switch), with one fixed command
(vx, vy, wz) per run, no observation noise, no random episode start. After a settling time the
probe measures, over the surviving envs, the base velocity in the heading frame (the frame the
commands and the tracking reward use: x along the horizontal projection of the body's x axis
plus its z axis, so the back's direction when standing on the front legs), the share of steps
above the task's upright threshold (the spec's, 1.4 rad), the share with the head on the ground
and each front foot's contact share, e.g.::

    UNIGAIT_SERVER_BIN=target/release/unigait-server \
        .venv/bin/python tools/probe_biped_walk.py assets/policies/unified_flat/model.pt

Every slice of o_t and e_t comes from the session spec by name; the angular velocity's
scale from the package's observation table (the spec does not publish scales).

A walking biped follows the sign and roughly the size of vx, and turns at wz (the probe
reports the world yaw rate too); one that stands in place moves at a few cm/s whatever it is
told. The tracking error |v* - v| (what `unigait eval` averages) is
split into the error of each env's mean velocity over the measured window (how far off its
walk is) and what the step-to-step sway adds on top. The sway is reported along and across the
heading, with the frequency where the sideways sway is strongest (a stride's rocking shows at
the gait's 2.2 Hz), next to the trunk's tilt rate: its angular speed about the two horizontal
axes, which tells a trunk rocking from one that moves as a whole.
"""

from __future__ import annotations

import argparse

import mujoco
import numpy as np
import torch
from unigait.client import SessionConfig, Spec, open_session
from unigait.env import ObservationHistory, TorchVecEnv
from unigait.export import load_policy
from unigait.mujoco.model import DEFAULT_Q, build_model
from unigait.mujoco.observation import OBS_SCALE
from unigait.server_process import LocalServer


class ObsFields:
    """Where the probe's inputs sit in o_t and e_t, all looked up by name in the spec."""

    def __init__(self, spec: Spec) -> None:
        phi = spec.obs.field("phi")
        self.gravity_y, self.pitch, self.gravity_z = phi.offset, phi.offset + 1, phi.offset + 2
        self.omega = spec.obs.slice("omega")
        # o_t holds omega times its scale; the spec carries no scales, the package's table does.
        self.omega_scale = torch.from_numpy(OBS_SCALE[self.omega])
        self.q = spec.obs.slice("q")
        self.velocity = spec.labels.slice("base_lin_vel")
        contact = spec.labels.field("foot_contact")
        # Feet in FL, FR, RL, RR order: the first two are the front feet.
        self.front_contact = slice(contact.offset, contact.offset + 2)
        self.upright_pitch = spec.upright_pitch


def overrides(vx: float, vy: float, wz: float) -> str:
    """Biped mode only, one command for the whole episode, noise-free observations."""
    return (
        "[modes]\nbiped_probability = 1.0\nresampling_time_s = 60.0\n"
        "[env]\nrandom_initial_episode_step = false\n"
        "[noise]\nenabled = false\n"
        f"[commands]\nresampling_time_s = 60.0\nzero_below = 0.0\n"
        f"biped = {{ vx = [{vx}, {vx}], vy = [{vy}, {vy}], wz = [{wz}, {wz}] }}\n"
    )


def heading_frame(obs: torch.Tensor, at: ObsFields) -> torch.Tensor:
    """[N, 3, 3] the world's heading-frame axes (forward, left, up) in the base frame, from o_t.

    o_t's orientation part is (gravity y, Euler pitch, gravity z) in the base frame; gravity x
    is sin(pitch). The heading axis is (1, 0, 1) of the base frame made horizontal: the rule of
    ``unigait.mujoco.vec_env.heading_direction``, which needs the world rotation o_t lacks.
    """
    pitch = obs[:, at.pitch]
    gravity = torch.stack([torch.sin(pitch), obs[:, at.gravity_y], obs[:, at.gravity_z]], dim=1)
    up = -gravity / gravity.norm(dim=1, keepdim=True)
    forward = torch.tensor([1.0, 0.0, 1.0]).expand_as(up)
    forward = forward - (forward * up).sum(1, keepdim=True) * up
    forward = forward / forward.norm(dim=1, keepdim=True)
    left = torch.cross(up, forward, dim=1)
    return torch.stack([forward, left, up], dim=1)


def in_heading_frame(frame: torch.Tensor, base_vector: torch.Tensor) -> torch.Tensor:
    """[N, 3] a base-frame vector's (forward, left, up) components in the heading frame.

    For the velocity label: the velocity the commands are given in. For o_t's angular velocity:
    the world yaw rate (up) and the trunk's tilt rate (forward and left: its rocking).
    """
    return torch.einsum("nij,nj->ni", frame, base_vector)


class Sway:
    """Step-to-step sway of the heading-frame velocity: what is left after each env's mean.

    `series` is [T, N, 2] (forward, left) at 50 Hz for the envs alive over the whole window.
    The strongest frequency tells a stride's rocking (the gait's 2.2 Hz) from slow wandering.
    """

    def __init__(self, series: torch.Tensor, dt: float = 0.02) -> None:
        x = (series - series.mean(0)).numpy()
        self.rms, self.peak_hz = np.zeros(2), np.zeros(2)
        if x.size:  # no env alive over the whole window: nothing to report
            self.rms = np.sqrt((x**2).mean(axis=(0, 1)))
            power = (np.abs(np.fft.rfft(x, axis=0)) ** 2).sum(1)
            self.peak_hz = np.fft.rfftfreq(x.shape[0], dt)[1:][power[1:].argmax(0)]


class ActionNoise:
    """The policy's own Gaussian noise on its mean actions when ``sampled``, none otherwise.

    Sampled actions are how the training rollouts act; the generator is seeded, so a probe repeats.
    """

    def __init__(self, checkpoint: str, sampled: bool, seed: int) -> None:
        state = torch.load(checkpoint, map_location="cpu", weights_only=False)
        log_std = state["actor_critic"]["log_std"]
        self.std = log_std.exp() if sampled else torch.zeros_like(log_std)
        self.generator = torch.Generator().manual_seed(seed)

    def __call__(self, mean: torch.Tensor) -> torch.Tensor:
        """Actions around ``mean``."""
        return mean + self.std * torch.randn(mean.shape, generator=self.generator)


def yaw_kernel(error: torch.Tensor) -> float:
    """Mean of the yaw-rate tracking reward's kernel, exp(-4 e^2), over the measured steps.

    Computed on the error as measured and again with its mean (the bias) taken out, it tells
    what the bias costs the reward: under the step-to-step noise of a sampled policy, little.
    """
    return float(torch.exp(-4.0 * error.pow(2)).mean())


class FrontLegReach:
    """How far a front foot moves sideways (heading frame) per radian of its leg's joints.

    The norm of the foot Jacobian's lateral row over the leg's three joints, from MuJoCo's
    kinematics of our URDF at the measured pose (base tilt from o_t, joint angles from o_t). On
    four legs at the default pose it is ~0.3 m/rad (the hip abduction swings the leg sideways);
    standing on the front legs the abduction axis (the base's x axis) points down, and a foot
    right under its hip has almost no sideways reach: the leg is singular in that direction.
    """

    def __init__(self, q: slice) -> None:
        self.q = q  # o_t's joint angles (minus the defaults)
        self.go2 = build_model()
        self.data = mujoco.MjData(self.go2.model)
        self.jacp = np.zeros((3, self.go2.model.nv))

    def __call__(self, obs: np.ndarray, world_from_base: np.ndarray) -> float:
        """Mean over both front feet, for one env's o_t and :func:`heading_frame` rows."""
        go2, d = self.go2, self.data
        mujoco.mju_mat2Quat(d.qpos[3:7], world_from_base.astype(np.float64).reshape(-1))
        d.qpos[go2.qpos_adr] = DEFAULT_Q + obs[self.q]
        mujoco.mj_kinematics(go2.model, d)
        mujoco.mj_comPos(go2.model, d)
        reach = []
        for leg in (0, 1):
            mujoco.mj_jacGeom(go2.model, d, self.jacp, None, int(go2.foot_geoms[leg]))
            reach.append(np.linalg.norm(self.jacp[1, go2.dof_adr[3 * leg : 3 * leg + 3]]))
        return float(np.mean(reach))


def probe(
    checkpoint: str,
    command: tuple[float, float, float],
    envs: int,
    steps: int,
    settle: int,
    seed: int,
    sampled: bool = False,
) -> str:
    """One run at ``command`` (vx, vy, wz): the line of figures the module docstring lists.

    ``sampled`` draws each action from the policy's Gaussian (its learned std), as training's
    rollouts do, instead of taking its mean: a gait can differ between the two.
    """
    vx, vy, wz = command
    policy, dims, engine = load_policy(checkpoint)
    noise = ActionNoise(checkpoint, sampled, seed)
    on_engine = f'[physics]\nengine = "{engine}"\n'  # the one it trained on (decision 0026)
    with LocalServer() as server:
        task = overrides(vx, vy, wz) + on_engine
        config = SessionConfig(num_envs=envs, seed=seed, task_overrides_toml=task)
        env = TorchVecEnv(open_session(server.address, config), "cpu")
        at = ObsFields(env.spec)
        history = ObservationHistory(envs, 3, dims["obs_dim"], torch.device("cpu"))
        history.reset(env.last.obs)
        alive = torch.ones(envs, dtype=torch.bool)
        velocity, upright, head, front, error, turn, tilt = [], [], [], [], [], [], []
        series, kept = [], torch.ones(envs, dtype=torch.bool)  # every env's velocity, for the sway
        reach_of, reach = FrontLegReach(at.q), []
        target = torch.tensor([vx, vy])
        velocity_sum = torch.zeros(envs, 2)
        counted = torch.zeros(envs)
        for t in range(steps):
            with torch.no_grad():
                actions = policy(history.flat.view(envs, 3, -1))
                actions = noise(actions)
            out = env.step(actions)
            history.push(out.obs, out.dones)
            alive &= ~out.terminated
            if t < settle:
                continue
            m = alive & ~out.dones
            kept &= m
            frame = heading_frame(out.obs, at)
            v_all = in_heading_frame(frame, out.labels[:, at.velocity])[:, :2]
            series.append(v_all)
            frame, v_now = frame[m], v_all[m]
            omega = in_heading_frame(frame, out.obs[m, at.omega] / at.omega_scale)
            tilt.append(omega[:, :2].norm(dim=1))
            velocity.append(v_now)
            error.append((v_now - target).norm(dim=1))
            turn.append(omega[:, 2])
            velocity_sum[m] += v_now
            counted[m] += 1
            upright.append(out.obs[m, at.pitch] > at.upright_pitch)
            head.append(out.head_contact[m].bool())
            front.append(out.labels[m, at.front_contact] > 0.5)
            if t % 10 == 0:  # a pose every 0.2 s is plenty for a stance's mean
                poses = zip(out.obs[m].numpy(), frame.numpy(), strict=True)
                reach += [reach_of(o, f) for o, f in poses]
        env.close()
    v = torch.cat(velocity)
    w = torch.cat(turn)
    sway = Sway(torch.stack(series)[:, kept])
    measured = counted > 0
    env_mean = velocity_sum[measured] / counted[measured].unsqueeze(1)
    return (
        f"vx {vx:+.2f} vy {vy:+.2f} wz {wz:+.2f}: "
        f"forward {v[:, 0].mean():+.3f} m/s, left {v[:, 1].mean():+.3f} m/s, "
        f"|v| {v.norm(dim=1).mean():.3f} m/s, error {torch.cat(error).mean():.3f} m/s "
        f"(of the envs' mean velocity {(env_mean - target).norm(dim=1).mean():.3f}), "
        f"yaw rate {w.mean():+.3f} rad/s (error {(w - wz).abs().mean():.3f}; "
        f"kernel exp(-4 e^2) {yaw_kernel(w - wz):.3f}, without the bias "
        f"{yaw_kernel(w - w.mean()):.3f}), "
        f"sway forward {sway.rms[0]:.3f} / left {sway.rms[1]:.3f} m/s rms "
        f"(left's strongest at {sway.peak_hz[1]:.1f} Hz), "
        f"tilt rate {torch.cat(tilt).pow(2).mean().sqrt():.2f} rad/s rms, "
        f"upright {torch.cat(upright).float().mean():.2f}, "
        f"head down {torch.cat(head).float().mean():.2f}, "
        f"front feet's sideways reach {np.mean(reach):.3f} m/rad, front feet down "
        + "/".join(f"{x:.2f}" for x in torch.cat(front).float().mean(0).tolist())
        + f", alive {int(alive.sum())}/{envs}"
    )


def main() -> None:
    """Parse the command line and print one line per --vx."""
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    p.add_argument("checkpoint", help="model_*.pt")
    p.add_argument("--vx", type=float, nargs="+", default=[-0.4, 0.0, 0.4])
    p.add_argument("--vy", type=float, default=0.0, help="lateral command of every run")
    p.add_argument("--wz", type=float, default=0.0, help="yaw-rate command of every run")
    p.add_argument("--envs", type=int, default=32)
    p.add_argument("--steps", type=int, default=400, help="policy steps (50 per second)")
    p.add_argument("--settle", type=int, default=150, help="steps before measuring")
    p.add_argument("--seed", type=int, default=5)
    p.add_argument("--sampled", action="store_true", help="actions drawn with the policy's std")
    a = p.parse_args()
    for vx in a.vx:
        command = (vx, a.vy, a.wz)
        line = probe(a.checkpoint, command, a.envs, a.steps, a.settle, a.seed, a.sampled)
        print(line, flush=True)


if __name__ == "__main__":
    main()
