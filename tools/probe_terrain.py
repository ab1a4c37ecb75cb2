r"""Where does a checkpoint stop on a terrain? Progress and reward terms per pinned tile level.

Every env sits on one pinned tile (``--terrain stairs_up``, level by level), in one mode for the
whole episode with one fixed command, noise-free, as in ``probe_biped_walk.py``. Per level the
probe reports the distance walked along the heading (the velocity label integrated in the
heading frame: the distance the curriculum's promotion counts), how far the base got from where
it stood (its reach, which decision record 0038 judges: a robot that paces along a riser walks
along its heading without getting farther), the share of envs that made the
curriculum's promotion distance (0.7 of the commanded distance, 2 m at least) and its demotion
line (0.5), the share that fell, and the reward terms whose per-step mean differs most from the
same policy on flat ground (where the terrain costs it reward, and what it is paid for), e.g.::

    UNIGAIT_SERVER_BIN=target/release/unigait-server .venv/bin/python tools/probe_terrain.py \
        assets/training/unified_terrain/01_terrain/model_latest.pt --terrain stairs_up \
        --levels 0 1 2 3 --mode quad --vx 0.5

``--lift DELTA ...`` runs each level once per offset added to the ``--joint`` actions (calf or
thigh) of ``--legs`` over each foot's clock swing window (a half sine, as ``probe_gait_clock.py
--lift``): would a higher swing of those feet, or one reaching farther, climb where the policy's
own does not? Each run also reports the share of envs whose base got past the tile's edge (half
a tile from where it stood): out of a stairs-up pit or up a slope-up pyramid; the share that
stopped there (their farthest reach within a step of the edge, standing at the end); and the
collision term (thigh and calf contacts) per step of those that stopped and of the others.
"""

from __future__ import annotations

import argparse

import torch
from probe_biped_walk import ActionNoise, ObsFields, heading_frame, in_heading_frame
from probe_gait_clock import clock_phase, swing_lift
from unigait.client import SessionConfig, open_session
from unigait.env import ObservationHistory, TorchVecEnv
from unigait.export import load_policy
from unigait.server_process import LocalServer

DT = 0.02
PROMOTE, DEMOTE = (
    0.7,
    0.5,
)  # the curriculum's shares of the commanded distance (decision 0022)
MIN_PROMOTE_M = 2.0
GAIT_PERIOD_S, GAIT_SWING_RATIO = 0.45, 0.4  # the task's [gait] defaults
MAX_DRAWN = 64  # the envs a step returns poses of
TILE_EDGE_M = 4.0  # half the default 8 m tile: the spawn point to the tile's edge
# An env stopped at the tile's edge: its farthest reach within these bounds (m), standing at the
# end. The top riser of a stairs-up pit is 0.3 m inside the edge, the next tile's first one
# 0.3 m beyond it; a robot that crossed walks on for metres.
STOPPED_AT_EDGE_M = (TILE_EDGE_M - 0.2, TILE_EDGE_M + 0.4)
LEGS = {"front": ("FL", "FR"), "hind": ("RL", "RR"), "all": ("FL", "FR", "RL", "RR")}
FOOT = {"FL": 0, "FR": 1, "RL": 2, "RR": 3}


def overrides(mode: str, vx: float, episode_s: float) -> str:
    """One mode, one forward command for the whole episode, noise-free observations."""
    p = 1.0 if mode == "biped" else 0.0
    return (
        f"[modes]\nbiped_probability = {p}\nresampling_time_s = 600.0\n"
        f"[env]\nrandom_initial_episode_step = false\nepisode_length_s = {episode_s}\n"
        "[noise]\nenabled = false\n"
        "[commands]\nresampling_time_s = 600.0\nzero_below = 0.0\n"
        f"{mode} = {{ vx = [{vx}, {vx}], vy = [0.0, 0.0], wz = [0.0, 0.0] }}\n"
    )


class Rollout:
    """One session's episode: distance along the heading per env, falls, reward per term."""

    def __init__(
        self,
        distance: torch.Tensor,
        estimated: torch.Tensor,
        fell: torch.Tensor,
        terms: torch.Tensor,
        apex: torch.Tensor,
        reach: torch.Tensor,
        collision: torch.Tensor,
    ) -> None:
        self.distance, self.estimated, self.fell, self.terms = distance, estimated, fell, terms
        self.apex = apex  # [4] the 90th percentile of each foot sole's height over the terrain
        # [min(N, 64)] the farthest each env's base got from where it stood after its first step
        # (m): what decision record 0038 judges, where `distance` counts turns in full.
        self.reach = reach
        # [N] each env's collision term per step while it stood (the term as paid, weight and
        # dt included): how much its thighs and calves touch the terrain.
        self.collision = collision

    def stopped_at_edge(self) -> torch.Tensor:
        """[min(N, 64)] envs standing at the end whose farthest reach stayed at the tile's edge."""
        lo, hi = STOPPED_AT_EDGE_M
        standing = ~self.fell[: len(self.reach)]
        return standing & (self.reach >= lo) & (self.reach <= hi)


def rollout(
    server: LocalServer,
    checkpoint: str,
    terrain: str,
    level: int,
    mode: str,
    vx: float,
    envs: int,
    steps: int,
    seed: int,
    sampled: bool = False,
    extra_toml: str = "",
    lift: float = 0.0,
    legs: str = "all",
    joint: str = "calf",
) -> tuple[Rollout, tuple[str, ...]]:
    """Run ``steps`` policy steps (no env survives past its first episode in the counts).

    ``sampled`` draws each action from the policy's Gaussian, as the training rollouts (and
    so the curriculum's promotions) do, instead of taking its mean. ``extra_toml`` is appended
    to the task overrides (tables the probe does not set itself, e.g. ``[rewards]``). ``lift``
    is added to the ``joint`` actions of ``legs`` over each foot's clock swing window.
    """
    policy, dims, engine = load_policy(checkpoint)
    noise = ActionNoise(checkpoint, sampled, seed)
    config = SessionConfig(
        num_envs=envs,
        seed=seed,
        # On the engine the checkpoint trained on (decision record 0026).
        task_overrides_toml=overrides(mode, vx, steps * DT + 1.0)
        + f'[physics]\nengine = "{engine}"\n'
        + extra_toml,
        terrain=terrain,
        terrain_level=level,
    )
    env = TorchVecEnv(open_session(server.address, config), "cpu")
    at = ObsFields(env.spec)
    history = ObservationHistory(envs, 3, dims["obs_dim"], torch.device("cpu"))
    history.reset(env.last.obs)
    alive = torch.ones(envs, dtype=torch.bool)
    distance, estimated = torch.zeros(envs), torch.zeros(envs)
    terms = torch.zeros(len(env.spec.reward_terms))
    collision_at = env.spec.reward_terms.index("collision")
    collision, stood = torch.zeros(envs), torch.zeros(envs)
    counted = 0
    foot_height = env.spec.labels.slice("foot_height")
    heights = []
    drawn = list(range(min(envs, MAX_DRAWN)))
    start: torch.Tensor | None = None
    reach = torch.zeros(len(drawn))
    spec = env.spec
    lifted = [
        (
            FOOT[leg],
            next(i for i, n in enumerate(spec.joint_names) if n.startswith(f"{leg}_{joint}")),
        )
        for leg in LEGS[legs]
    ]
    clock = spec.obs.slice("clock")
    before = env.last.obs[:, clock].clone()
    raise_by = torch.zeros(envs, 4)
    for _ in range(steps):
        with torch.no_grad():
            actions = noise(policy(history.flat.view(envs, 3, -1))).clone()
        for foot, index in lifted:
            actions[:, index] += lift * raise_by[:, foot]
        out = env.step(actions, draw_envs=drawn)
        phase = clock_phase(out.obs[:, clock], before)
        before = out.obs[:, clock].clone()
        raise_by = swing_lift(phase, GAIT_PERIOD_S, GAIT_SWING_RATIO)
        if out.body_poses is not None:
            base = torch.as_tensor(out.body_poses[:, 0, :2].copy())
            start = base if start is None else start
            reach = torch.where(
                alive[: len(drawn)], torch.maximum(reach, (base - start).norm(dim=1)), reach
            )
        history.push(out.obs, out.dones)
        frame = heading_frame(out.obs, at)
        forward = in_heading_frame(frame, out.labels[:, at.velocity])[:, 0]
        distance += torch.where(alive, forward * DT, 0.0)
        with torch.no_grad():  # e_t of the same o_t as the label: the policy's next input
            estimate = policy.estimator(history.flat.view(envs, -1))
        believed = in_heading_frame(frame, estimate[:, at.velocity])[:, 0]
        estimated += torch.where(alive, believed * DT, 0.0)
        if out.reward_terms is not None and alive.any():
            terms += out.reward_terms[alive].sum(0)
            counted += int(alive.sum())
            collision += torch.where(alive, out.reward_terms[:, collision_at], 0.0)
            stood += alive.float()
        heights.append(out.labels[alive, foot_height])
        alive &= ~out.dones
    env.close()
    fell = ~alive
    apex = torch.cat(heights).quantile(0.9, dim=0)
    per_step = collision / stood.clamp(min=1.0)
    rollout = Rollout(distance, estimated, fell, terms / max(counted, 1), apex, reach, per_step)
    return rollout, env.spec.reward_terms


def mean_or_nan(x: torch.Tensor) -> float:
    """The mean, or NaN for no envs."""
    return float(x.mean()) if len(x) else float("nan")


def main() -> None:
    """Parse the command line and print one block per level."""
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    p.add_argument("checkpoint", help="model_*.pt")
    p.add_argument("--terrain", default="stairs_up")
    p.add_argument("--levels", type=int, nargs="+", default=[0, 1, 2, 3])
    p.add_argument("--mode", choices=["quad", "biped"], default="quad")
    p.add_argument("--vx", type=float, default=0.5, help="forward command (m/s)")
    p.add_argument("--envs", type=int, default=32)
    p.add_argument("--steps", type=int, default=600, help="policy steps (50 per second)")
    p.add_argument("--seed", type=int, default=5)
    p.add_argument("--terms", type=int, default=6, help="reward terms listed per level")
    p.add_argument("--sampled", action="store_true", help="actions drawn with the policy's std")
    p.add_argument("--lift", type=float, nargs="+", default=[0.0], help="action offsets (rad)")
    p.add_argument("--legs", choices=sorted(LEGS), default="all", help="whose joints --lift moves")
    p.add_argument("--joint", choices=["calf", "thigh"], default="calf", help="which --lift moves")
    p.add_argument(
        "--task-toml",
        default="",
        help="more task overrides, e.g. '[rewards]\\nfoot_clearance_weighting = \"swing_phase\"' "
        "(\\n is a newline); rewards do not move the robot, so they can be priced both ways",
    )
    a = p.parse_args()
    extra = a.task_toml.replace("\\n", "\n")
    commanded = abs(a.vx) * a.steps * DT
    promote_m = max(PROMOTE * commanded, MIN_PROMOTE_M)
    with LocalServer() as server:

        def run(terrain: str, level: int, lift: float = 0.0) -> tuple[Rollout, tuple[str, ...]]:
            return rollout(
                server,
                a.checkpoint,
                terrain,
                level,
                a.mode,
                a.vx,
                a.envs,
                a.steps,
                a.seed,
                a.sampled,
                extra,
                lift,
                a.legs,
                a.joint,
            )

        flat, names = run("flat", 0)
        print(
            f"flat: walked {flat.distance.mean():+.2f} m of {commanded:.1f} commanded "
            f"(estimated {flat.estimated.mean():+.2f}), "
            f"fell {flat.fell.float().mean():.2f}, feet's 90th percentile height "
            + "/".join(f"{h:.3f}" for h in flat.apex.tolist()),
            flush=True,
        )
        for level, lift in ((level, lift) for level in a.levels for lift in a.lift):
            r, _ = run(a.terrain, level, lift)
            walked = r.distance * (1.0 if a.vx >= 0 else -1.0)
            delta = r.terms - flat.terms
            worst = delta.abs().argsort(descending=True)[: a.terms]
            listed = ", ".join(
                f"{names[i]} {r.terms[i]:+.4f} ({delta[i]:+.4f})" for i in worst.tolist()
            )
            lifted = f" lift {lift:+.2f} ({a.legs} {a.joint})" if len(a.lift) > 1 or lift else ""
            stopped = r.stopped_at_edge()
            others = ~stopped & ~r.fell[: len(stopped)]
            drawn_collision = r.collision[: len(stopped)]
            print(
                f"{a.terrain} level {level}{lifted}: walked {walked.mean():+.2f} m "
                f"(quartiles {walked.quantile(0.25):+.2f} / {walked.median():+.2f} / "
                f"{walked.quantile(0.75):+.2f}; estimated {r.estimated.mean():+.2f}), "
                f"reach {r.reach.mean():.2f} m (quartiles {r.reach.quantile(0.25):.2f} / "
                f"{r.reach.median():.2f} / {r.reach.quantile(0.75):.2f}; past the tile's edge "
                f"{(r.reach >= TILE_EDGE_M).float().mean():.2f}, stopped there "
                f"{stopped.float().mean():.2f}), collision per step stopped "
                f"{mean_or_nan(drawn_collision[stopped]):+.4f}, the others "
                f"{mean_or_nan(drawn_collision[others]):+.4f}, "
                f"promoted {(walked > promote_m).float().mean():.2f}, "
                f"demoted {(walked < DEMOTE * commanded).float().mean():.2f}, "
                f"fell {r.fell.float().mean():.2f}, feet's 90th percentile height "
                + "/".join(f"{h:.3f}" for h in r.apex.tolist())
                + f"; per step (vs flat): {listed}",
                flush=True,
            )


if __name__ == "__main__":
    main()
