r"""Does a checkpoint step on its gait clock, and what would a higher swing cost it?

Every env walks flat ground in one mode with one fixed forward command, noise-free and without
pushes, under a recipe stage's task settings (``--recipe``, ``--stage``: the reward weights the
policy trained with). After a settling second the probe reports, per mode:

- how often each foot touches down (contact onsets per second) against the clock's rate
  (1 / ``gait.period_s``), and each foot's share of steps in contact;
- the sole's height mid-swing: over the middle half of the clock's swing window of that foot
  (local phase 0.1-0.3 of the default 0.4 swing), where the swing-phase clearance term prices
  it (decision record 0039);
- the first foot's (FL's) contact share and sole height by its clock phase, in tenths of the
  cycle (the swing window is the first ``gait.swing_ratio`` of it): a foot on its clock is in the
  air through its swing window and down through its stance, one off it the same throughout;
- each swing's air time at its touchdown, counted as the `biped_feet_air_time` term counts it
  (decision record 0040: a contact now or at the step before is a contact), and that term's
  raw per-step mean for the mode's feet against the clock's swing;
- the speed along the heading, falls, and every reward term's per-step mean.

``--lift DELTA`` adds DELTA to the calf action (``--joint``) of each stance-mode foot over its
clock swing window (a half sine, one step early since an action acts over the next step): what
a higher swing pays and costs the other terms when the policy itself does not swing higher, e.g.::

    UNIGAIT_SERVER_BIN=target/release/unigait-server .venv/bin/python tools/probe_gait_clock.py \
        assets/training/unified_terrain/26_reach_3/model_latest.pt --mode biped --vx 0.4 \
        --lift 0 -2
"""

from __future__ import annotations

import argparse
import math
from dataclasses import dataclass
from typing import Any

import torch
from probe_biped_walk import ObsFields, heading_frame, in_heading_frame
from unigait.client import SessionConfig, open_session
from unigait.config import merged, toml_document
from unigait.env import ObservationHistory, TorchVecEnv
from unigait.export import load_policy
from unigait.recipes import load_recipe
from unigait.server_process import LocalServer

DT = 0.02
SETTLE_STEPS = 50
MID_SWING = (0.1, 0.3)  # local phase, the middle half of the default 0.4 swing window
PHASE_BINS = 10


def task_toml(stage_task: dict[str, Any], mode: str, vx: float, engine: str) -> str:
    """The stage's task settings, one mode and one command for the whole run, noise-free."""
    probe = {
        "modes": {"biped_probability": 1.0 if mode == "biped" else 0.0, "resampling_time_s": 600.0},
        "env": {"random_initial_episode_step": False, "episode_length_s": 60.0},
        "noise": {"enabled": False},
        "randomization": {"push_interval_s": 1000.0},
        "commands": {
            "resampling_time_s": 600.0,
            "zero_below": 0.0,
            mode: {"vx": [vx, vx], "vy": [0.0, 0.0], "wz": [0.0, 0.0]},
        },
        "physics": {"engine": engine},
    }
    return toml_document(merged(stage_task, probe))


def clock_phase(now: torch.Tensor, before: torch.Tensor) -> torch.Tensor:
    """Local phase in [0, 1) from sin(2 pi phase) at two consecutive steps.

    Rising, the phase is within a quarter turn of 0; falling, within a quarter turn of 0.5.
    """
    base = torch.asin(now.clamp(-1.0, 1.0)) / (2 * math.pi)
    return torch.where(now >= before, base, 0.5 - base).remainder(1.0)


def swing_lift(phase: torch.Tensor, period: float, swing: float) -> torch.Tensor:
    """Each foot's lift share for the next action: a half sine over its clock swing window.

    Read one step ahead, since an action acts over the next step.
    """
    lead = (phase + DT / period).remainder(1.0)
    return torch.where(lead < swing, torch.sin(math.pi * lead / swing), 0.0)


@dataclass
class Probe:
    """One run's figures."""

    touchdowns_per_s: float
    air_time_s: float
    air_time_term: float
    contact_share: list[float]
    mid_swing_sole_m: float
    mid_swing_sole_p90_m: float
    speed_mps: float
    falls: int
    terms: dict[str, float]
    #: FL's contact share and mean sole height (m) per tenth of its clock cycle.
    contact_by_phase: list[float]
    sole_by_phase: list[float]


def run(server: LocalServer, args: argparse.Namespace, lift: float) -> Probe:
    """One session of ``args.envs`` envs for ``args.steps`` steps with ``lift`` on the calves."""
    policy, dims, engine = load_policy(args.checkpoint)
    stage = load_recipe(args.recipe).stages[args.stage]
    toml = task_toml(stage.config.env.task, args.mode, args.vx, engine)
    cfg = SessionConfig(num_envs=args.envs, seed=args.seed, task_overrides_toml=toml)
    env = TorchVecEnv(open_session(server.address, cfg), "cpu")
    spec, n = env.spec, args.envs
    at = ObsFields(spec)
    feet = [0, 1] if args.mode == "biped" else [0, 1, 2, 3]
    legs = ["FL", "FR", "RL", "RR"]
    joints = [
        next(
            i
            for i, name in enumerate(spec.joint_names)
            if name.startswith(legs[f]) and args.joint in name
        )
        for f in feet
    ]
    clock, contact = spec.obs.slice("clock"), spec.labels.field("foot_contact")
    sole = spec.labels.slice("foot_height")
    history = ObservationHistory(n, 3, dims["obs_dim"], torch.device("cpu"))
    history.reset(env.last.obs)
    before = env.last.obs[:, clock].clone()
    was = torch.ones(n, 4, dtype=torch.bool)
    air = torch.zeros(n, 4)  # the server's FeetAirTime, client-side
    swings: list[torch.Tensor] = []
    raise_by = torch.zeros(n, 4)
    fell = torch.zeros(n, dtype=torch.bool)
    onsets, foot_steps, mid, speeds = 0.0, 0.0, [], []
    bins = torch.zeros(3, PHASE_BINS)  # samples, contacts, sole heights of FL per phase tenth
    in_contact, term_sum, samples = torch.zeros(4), torch.zeros(len(spec.reward_terms)), 0
    for t in range(args.steps):
        with torch.no_grad():
            action = policy(history.flat.view(n, 3, -1)).clone()
        for f, j in zip(feet, joints, strict=True):
            action[:, j] += lift * raise_by[:, f]
        out = env.step(action, draw_envs=[])
        history.push(out.obs, out.dones)
        phase = clock_phase(out.obs[:, clock], before)
        before = out.obs[:, clock].clone()
        raise_by = swing_lift(phase, args.period, args.swing)
        now = out.labels[:, contact.offset : contact.offset + 4] > 0.5
        fell |= out.terminated
        if t >= SETTLE_STEPS:
            alive = ~fell
            onsets += float((now & ~was)[alive][:, feet].sum())
            foot_steps += float(alive.sum()) * len(feet)
            in_contact += now[alive].float().sum(0)
            tenth = (phase[alive][:, 0] * PHASE_BINS).long().clamp(0, PHASE_BINS - 1)
            bins[0].index_add_(0, tenth, torch.ones(len(tenth)))
            bins[1].index_add_(0, tenth, now[alive][:, 0].float())
            bins[2].index_add_(0, tenth, out.labels[alive][:, sole][:, 0])
            heights = out.labels[alive][:, sole][:, feet]
            window = (phase[alive][:, feet] > MID_SWING[0]) & (phase[alive][:, feet] < MID_SWING[1])
            mid.append(heights[window])
            velocity = in_heading_frame(heading_frame(out.obs, at), out.labels[:, at.velocity])
            speeds.append(velocity[alive][:, 0])
            term_sum += out.reward_terms[alive].sum(0)
            samples += int(alive.sum())
        down = now | was
        first = down & (air > 0)
        air += DT
        if t >= SETTLE_STEPS:
            swings.append(air[~fell][:, feet][first[~fell][:, feet]])
        air = torch.where(down, torch.zeros_like(air), air)
        was = now
    swing = torch.cat(mid)
    return Probe(
        touchdowns_per_s=onsets / foot_steps / DT,
        air_time_s=float(torch.cat(swings).mean()),
        air_time_term=float(
            (torch.cat(swings).clamp(max=args.period * args.swing) - args.period * args.swing).sum()
        )
        / max(samples, 1),
        contact_share=(in_contact[feet] / max(samples, 1)).tolist(),
        mid_swing_sole_m=float(swing.mean()),
        mid_swing_sole_p90_m=float(swing.quantile(0.9)),
        contact_by_phase=(bins[1] / bins[0].clamp(min=1)).tolist(),
        sole_by_phase=(bins[2] / bins[0].clamp(min=1)).tolist(),
        speed_mps=float(torch.cat(speeds).mean()),
        falls=int(fell.sum()),
        terms={
            name: float(term_sum[i]) / max(samples, 1) for i, name in enumerate(spec.reward_terms)
        },
    )


def main() -> None:
    """Print the figures of each ``--lift``, and each term's change against the first."""
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    p.add_argument("checkpoint", help="model_*.pt")
    p.add_argument("--recipe", default="unified_terrain", help="whose stage's task settings")
    p.add_argument("--stage", type=int, default=-1, help="stage index (default: the last)")
    p.add_argument("--mode", choices=["quad", "biped"], default="biped")
    p.add_argument("--vx", type=float, default=0.4, help="forward command (m/s)")
    p.add_argument("--lift", type=float, nargs="+", default=[0.0], help="calf action offsets")
    p.add_argument("--joint", choices=["hip", "thigh", "calf"], default="calf")
    p.add_argument("--period", type=float, default=0.45, help="the task's gait.period_s")
    p.add_argument("--swing", type=float, default=0.4, help="the task's gait.swing_ratio")
    p.add_argument("--envs", type=int, default=32)
    p.add_argument("--steps", type=int, default=400, help="policy steps (50 per second)")
    p.add_argument("--seed", type=int, default=7)
    args = p.parse_args()
    first: Probe | None = None
    with LocalServer() as server:
        for lift in args.lift:
            r = run(server, args, lift)
            print(
                f"{args.mode} lift {lift:+.2f}: touchdowns {r.touchdowns_per_s:.2f}/s per foot "
                f"(clock {1 / args.period:.2f}), swings {1000 * r.air_time_s:.0f} ms at touchdown "
                f"(air-time term {r.air_time_term:+.4f} a step, raw), contact share "
                + " ".join(f"{c:.2f}" for c in r.contact_share)
                + f", mid-swing sole {100 * r.mid_swing_sole_m:.1f} cm (p90 "
                f"{100 * r.mid_swing_sole_p90_m:.1f}), speed {r.speed_mps:.3f} m/s, falls "
                f"{r.falls}, reward {sum(r.terms.values()):+.4f} a step"
            )
            print(
                "   FL by clock phase (tenths): contact "
                + " ".join(f"{c:.2f}" for c in r.contact_by_phase)
                + " | sole cm "
                + " ".join(f"{100 * h:.1f}" for h in r.sole_by_phase)
            )
            base = first or r
            shown = sorted(r.terms, key=lambda k: -abs(r.terms[k]))
            print(
                "   "
                + " ".join(
                    f"{k} {r.terms[k]:+.4f}"
                    + (f" ({r.terms[k] - base.terms[k]:+.4f})" if first else "")
                    for k in shown
                    if abs(r.terms[k]) > 1e-4
                )
            )
            first = first or r


if __name__ == "__main__":
    main()
