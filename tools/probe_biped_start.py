r"""Does a checkpoint's policy hold a biped stance it is put in? Policy vs zero action.

Every env starts in biped mode at a pitch drawn from [--pitch LOW HIGH] (nose-down, rad), at
rest, no random episode start; both runs use the same seed, so the same starts. Prints, per
run, the median pitch over the surviving envs at a few steps, the share of them upright (above
the task's upright threshold from the spec, 1.4 rad), how many are still alive (no termination)
and the share of biped env-steps with the head on the ground, e.g.::

    UNIGAIT_SERVER_BIN=target/release/unigait-server \
        .venv/bin/python tools/probe_biped_start.py runs/unified_flat_v2/model_latest.pt \
        --pitch 1.45 1.55

A policy that has learned the stance keeps its robots above 1.4 rad; zero action (joint
targets at the default pose) lets them tip back to four legs within about a second.
"""

from __future__ import annotations

import argparse
import statistics

import torch
from unigait.client import SessionConfig, open_session
from unigait.env import ObservationHistory, TorchVecEnv
from unigait.export import load_policy
from unigait.modules import EstimatorActorPolicy
from unigait.server_process import LocalServer

REPORT_STEPS = (0, 5, 10, 25, 50, 100)


POSES = ("upright", "head down")


class TermsByPose:
    """Mean weighted reward per env-step of each term, split by pose.

    Poses: upright (pitch above the threshold) and head down (head on the ground, below it).
    Says whether the stance the policy has not found pays more per step than the head rest it
    holds.
    """

    def __init__(self, names: tuple[str, ...]) -> None:
        self.names = names
        self.sums = {pose: torch.zeros(len(names), dtype=torch.float64) for pose in POSES}
        self.counts = dict.fromkeys(POSES, 0)

    def add(self, pose: str, terms: torch.Tensor, mask: torch.Tensor) -> None:
        """Add the env-steps in ``mask`` (one step's envs) to ``pose``'s sums."""
        self.sums[pose] += terms[mask].double().sum(0)
        self.counts[pose] += int(mask.sum())

    def table(self) -> str:
        """The terms that are non-zero in either pose, with the per-pose sums and counts."""
        means = {p: self.sums[p] / max(self.counts[p], 1) for p in POSES}
        lines = [f"{'term':<28}" + "".join(f"{p:>14}" for p in POSES)]
        for i, name in enumerate(self.names):
            if any(abs(float(means[p][i])) > 0 for p in POSES):
                lines.append(f"{name:<28}" + "".join(f"{float(means[p][i]):14.5f}" for p in POSES))
        lines.append(
            f"{'sum (env-steps)':<28}"
            + "".join(f"{float(means[p].sum()):9.5f} ({self.counts[p]})" for p in POSES)
        )
        return "\n".join(lines)


def run(
    address: str,
    policy: EstimatorActorPolicy | None,
    obs_dim: int,
    args: argparse.Namespace,
    engine: str,
) -> tuple[str, TermsByPose | None]:
    """One batch of pitched starts, driven by ``policy`` (None: zero action).

    Returns a line of figures and, with ``--terms``, the surviving envs' reward terms by pose.
    """
    n = args.envs
    overrides = (
        "[modes]\nbiped_probability = 1.0\nresampling_time_s = 60.0\n"
        "[env]\nrandom_initial_episode_step = false\n"
        f"[init]\npitch = [{args.pitch[0]}, {args.pitch[1]}]\n"
        f'[physics]\nengine = "{engine}"\n'  # the one the checkpoint trained on
    )
    session = open_session(
        address,
        SessionConfig(
            num_envs=n,
            seed=args.seed,
            task_overrides_toml=overrides,
            reward_terms=args.terms,
        ),
    )
    env = TorchVecEnv(session, "cpu")
    pitch_index, upright_pitch = env.spec.pitch_index, env.spec.upright_pitch
    terms = TermsByPose(env.spec.reward_terms) if args.terms else None
    history = ObservationHistory(n, 3, obs_dim, torch.device("cpu"))
    history.reset(env.last.obs)
    alive = torch.ones(n, dtype=torch.bool)
    pitch = env.last.obs[:, pitch_index].clone()
    figures: list[str] = []
    head_steps = head_hits = 0
    for step in range(max(REPORT_STEPS) + 1):
        if step in REPORT_STEPS:
            live = pitch[alive].tolist()
            median = statistics.median(live) if live else float("nan")
            upright = sum(p > upright_pitch for p in live) / max(len(live), 1)
            figures.append(f"{step}: {median:.2f} ({upright:.0%} up, {len(live)} alive)")
        if step == max(REPORT_STEPS):
            break
        with torch.no_grad():
            actions = (
                torch.zeros(n, env.spec.num_actions)
                if policy is None
                else policy(history.flat.view(n, 3, -1))
            )
        out = env.step(actions)
        alive &= ~out.dones
        history.push(out.obs, out.dones)
        pitch = out.obs[:, pitch_index]
        if terms is not None and out.reward_terms is not None and out.head_contact is not None:
            terms.add("upright", out.reward_terms, alive & (pitch > upright_pitch))
            head_rest = alive & out.head_contact & (pitch <= upright_pitch)
            terms.add("head down", out.reward_terms, head_rest)
        if out.head_contact is not None:
            head_steps += int(alive.sum())
            head_hits += int((alive & out.head_contact).sum())
    env.close()
    head = f"{head_hits / head_steps:.0%}" if head_steps else "n/a"
    label = "zero action" if policy is None else "policy"
    line = f"{label:>11}: median pitch at step " + "; ".join(figures) + f"; head down {head}"
    return line, terms


def main() -> None:
    """Parse the command line; run the policy, then zero action, from the same starts."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("checkpoint")
    parser.add_argument("--pitch", type=float, nargs=2, default=(1.45, 1.55))
    parser.add_argument("--envs", type=int, default=64)
    parser.add_argument("--seed", type=int, default=7)
    parser.add_argument(
        "--terms",
        action="store_true",
        help="also print each reward term's mean per env-step, upright vs head down (both runs)",
    )
    args = parser.parse_args()
    policy, dims, engine = load_policy(args.checkpoint)
    with LocalServer() as server:
        for driver in (policy, None):
            line, terms = run(server.address, driver, dims["obs_dim"], args, engine)
            print(line)
            if terms is not None:
                print(terms.table())


if __name__ == "__main__":
    main()
