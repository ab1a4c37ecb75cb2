r"""Where would the curriculum move each mode? Verdicts on pinned tiles under a stage's own config.

Unlike ``probe_terrain.py`` (one mode, one straight command, noise-free), every env here lives
one episode as training does: the recipe stage's task config (its commands, mode switches,
randomisation and observation noise), actions drawn with the policy's std, on one pinned tile
per level. Each episode is then judged as a curriculum with a level per mode judges it
(decision record 0036): only the part walked in the mode the episode started in, against what
that mode's commands asked for, with the stage's promotion lines (``[terrain_curriculum]``). A
fall counts the rest of the episode as asked for at the last command, as the server does.
The shares promoted and demoted per level show where each mode's level settles, e.g.::

    UNIGAIT_SERVER_BIN=target/release/unigait-server .venv/bin/python tools/probe_curriculum.py \
        assets/training/unified_terrain/18_per_mode_levels/model_latest.pt \
        --recipe unified_terrain --stage 18 --terrain stairs_up --levels 0 1 2 3
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass

import torch
from probe_biped_walk import ActionNoise, ObsFields, heading_frame, in_heading_frame
from unigait.client import SessionConfig, open_session
from unigait.env import ObservationHistory, TorchVecEnv
from unigait.export import load_policy
from unigait.recipes import load_recipe
from unigait.server_process import LocalServer

DT = 0.02
BIPED, QUAD = 1, 2  # the wire's mode values
#: o_t holds the command times these scales (the server's observation table).
COMMAND_SCALE = torch.tensor([2.0, 2.0, 0.25])


@dataclass(frozen=True)
class Lines:
    """The stage's promotion and demotion shares per mode, and the minimum distance (m)."""

    promote: dict[int, float]
    demote: dict[int, float]
    min_distance: float

    @classmethod
    def of(cls, task: dict) -> Lines:
        """The server's defaults (0.7, 0.5, 2 m, the biped's the quad's) under ``task``'s."""
        rule = task.get("terrain_curriculum", {})
        up, down = rule.get("promote_share", 0.7), rule.get("demote_share", 0.5)
        return cls(
            promote={QUAD: up, BIPED: rule.get("promote_share_biped", up)},
            demote={QUAD: down, BIPED: rule.get("demote_share_biped", down)},
            min_distance=rule.get("promote_min_distance", 2.0),
        )


def episodes(
    server: LocalServer,
    checkpoint: str,
    task_toml: str,
    terrain: str,
    level: int,
    envs: int,
    seed: int,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Each env's first episode: (mode it started in, walked in it, asked for in it)."""
    policy, dims, _ = load_policy(checkpoint)
    noise = ActionNoise(checkpoint, True, seed)
    config = SessionConfig(
        num_envs=envs,
        seed=seed,
        task_overrides_toml=task_toml + "\n[env]\nrandom_initial_episode_step = false\n",
        terrain=terrain,
        terrain_level=level,
    )
    env = TorchVecEnv(open_session(server.address, config), "cpu")
    at = ObsFields(env.spec)
    command_at = env.spec.obs.slice("cmd")
    history = ObservationHistory(envs, 3, dims["obs_dim"], torch.device("cpu"))
    history.reset(env.last.obs)
    started = env.last.mode.clone()
    mode = started.clone()
    walked, asked = torch.zeros(envs), torch.zeros(envs)
    alive = torch.ones(envs, dtype=torch.bool)
    obs, step, steps = env.last.obs, 0, env.spec.max_episode_steps
    while alive.any() and step < steps:
        command = obs[:, command_at] / COMMAND_SCALE
        speed = command[:, :2].norm(dim=1)
        with torch.no_grad():
            actions = noise(policy(history.flat.view(envs, 3, -1)))
        out = env.step(actions)
        step += 1
        history.push(out.obs, out.dones)
        velocity = in_heading_frame(heading_frame(out.obs, at), out.labels[:, at.velocity])[:, :2]
        own = alive & (mode == started) & (speed > 0)
        along = (velocity * command[:, :2]).sum(1) / speed.clamp(min=1e-6)
        walked += torch.where(own, along * DT, 0.0)
        asked += torch.where(own, speed * DT, 0.0)
        # A fall: the rest of the episode counts as asked for at the last command.
        fell = own & out.terminated
        asked += torch.where(fell, speed * (steps - step) * DT, 0.0)
        alive &= ~out.dones
        mode, obs = out.mode, out.obs
    env.close()
    return started, walked, asked


def main() -> None:
    """Parse the command line and print one line per level and mode."""
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    p.add_argument("checkpoint", help="model_*.pt")
    p.add_argument("--recipe", default="unified_terrain")
    p.add_argument("--stage", type=int, required=True, help="the stage's number (1 = first)")
    p.add_argument("--terrain", default="stairs_up", help="a terrain type, or flat")
    p.add_argument("--levels", type=int, nargs="+", default=[0, 1, 2, 3])
    p.add_argument("--envs", type=int, default=64)
    p.add_argument("--seed", type=int, default=11)
    a = p.parse_args()
    stage = load_recipe(a.recipe).stages[a.stage - 1]
    task = stage.config.env.task
    lines = Lines.of(task)
    rule = task.get("terrain_curriculum", {})
    if rule.get("judge_reach") or rule.get("promote_min_reach"):
        # The reach needs the base's path and the commanded one (decision record 0038); this
        # probe counts the walked distance alone, so its verdicts are an upper bound there.
        print(
            "note: this stage judges reach (judge_reach / promote_min_reach); the verdicts below"
            " count the walked distance alone and overstate promotions",
            flush=True,
        )
    with LocalServer() as server:
        for level in a.levels:
            started, walked, asked = episodes(
                server, a.checkpoint, stage.config.env.task_toml(), a.terrain, level, a.envs, a.seed
            )
            for mode, name in ((QUAD, "quad"), (BIPED, "biped")):
                sel = started == mode
                w, d = walked[sel], asked[sel]
                up = (w > lines.promote[mode] * d) & (w >= lines.min_distance)
                down = ~up & (w < lines.demote[mode] * d)
                print(
                    f"{a.terrain} level {level}, {int(sel.sum())} {name}-started episodes: "
                    f"walked {w.mean():.2f} of {d.mean():.2f} m asked, "
                    f"promoted {up.float().mean():.2f}, demoted {down.float().mean():.2f}",
                    flush=True,
                )


if __name__ == "__main__":
    main()
