"""Our learner against rsl_rl's own ``OnPolicyRunner`` on the same envs (quad mode, flat).

Both runs use one server, the same session config and seed, the same number of iterations and
24 steps per env per iteration; both measure, per iteration, the rollout mean of the weighted
``quad_tracking_lin_vel`` term per env step and the mean length of the episodes that ended. The
estimator is ours alone (rsl_rl's actor sees the history without an estimate).

``python -m unigait compare-rsl-rl --num-envs 256 --iterations 100 --out runs/compare``
writes ``compare.csv`` and ``compare.png``.
"""

from __future__ import annotations

import csv
from pathlib import Path
from typing import Any

import torch

from unigait.client import SessionConfig
from unigait.env.torch_env import TorchVecEnv

QUAD_ONLY = "[modes]\nbiped_probability = 0.0\n"
TERM = "quad_tracking_lin_vel"


def _session(num_envs: int, seed: int) -> SessionConfig:
    return SessionConfig(
        num_envs=num_envs, seed=seed, task_overrides_toml=QUAD_ONLY, reward_terms=True
    )


def run_ours(address: str, num_envs: int, iterations: int, seed: int) -> list[dict[str, float]]:
    """Our learner (PPO + concurrent estimator, Table III defaults)."""
    from unigait.config import load_config
    from unigait.runners import OnPolicyRunner

    torch.manual_seed(seed)
    cfg = load_config(None, ["runner.quiet=true", f"runner.seed={seed}"])
    env = TorchVecEnv.connect(address, _session(num_envs, seed))
    try:
        history = OnPolicyRunner(env, cfg, None).learn(iterations)
    finally:
        env.close()
    return [
        {
            "iteration": h["iteration"],
            "tracking": h[f"step_reward/{TERM}"],
            "episode_length": h["mean_episode_length"],
            "learning_rate": h["learning_rate"],
            "kl": h["kl"],
        }
        for h in history
    ]


def run_rsl_rl(
    address: str, num_envs: int, iterations: int, seed: int, obs_normalization: bool = False
) -> list[dict[str, float]]:
    """rsl_rl 5.x's ``OnPolicyRunner`` on :class:`~unigait.env.rsl_rl_env.RslRlVecEnv`."""
    from rsl_rl.runners import OnPolicyRunner as RslOnPolicyRunner

    from unigait.env.rsl_rl_env import RslRlVecEnv, rsl_rl_train_cfg

    class Recording(RslRlVecEnv):
        """Measures what our runner logs, with the same definitions."""

        def __init__(self, env: TorchVecEnv) -> None:
            super().__init__(env)
            self.term = list(self.spec.reward_terms).index(TERM)
            self.rows: list[dict[str, float]] = []
            # Steps since the learner saw each episode begin (as our runner counts them: the
            # server's first episodes start at random steps).
            self.since_start = torch.zeros(self.num_envs, dtype=torch.int64)
            self._clear()

        def _clear(self) -> None:
            self.steps, self.term_sum = 0, 0.0
            self.lengths: list[float] = []

        def step(self, actions: torch.Tensor) -> tuple[Any, torch.Tensor, torch.Tensor, dict]:
            out = super().step(actions)
            last = self.env.last
            if last.reward_terms is not None:
                self.term_sum += float(last.reward_terms[:, self.term].sum())
            self.since_start += 1
            done = last.dones.cpu()
            self.lengths += self.since_start[done].tolist()
            self.since_start[done] = 0
            self.steps += 1
            if self.steps == 24:
                self.rows.append(
                    {
                        "iteration": float(len(self.rows) + 1),
                        "tracking": self.term_sum / (24 * self.num_envs),
                        "episode_length": (
                            sum(self.lengths) / len(self.lengths) if self.lengths else float("nan")
                        ),
                    }
                )
                self._clear()
            return out

    torch.manual_seed(seed)
    env = Recording(TorchVecEnv.connect(address, _session(num_envs, seed)))
    cfg = rsl_rl_train_cfg(num_steps_per_env=24, logger="tensorboard")
    cfg["actor"]["obs_normalization"] = obs_normalization
    cfg["critic"]["obs_normalization"] = obs_normalization
    cfg["seed"] = seed
    try:
        runner = RslOnPolicyRunner(env, cfg, None, "cpu")
        for _ in range(iterations):
            runner.learn(num_learning_iterations=1)
            if env.rows:
                env.rows[-1]["learning_rate"] = float(runner.alg.learning_rate)
    finally:
        env.close()
    return env.rows


def write(out: Path, runs: dict[str, list[dict[str, float]]]) -> None:
    """``compare.csv`` (one row per learner and iteration) and ``compare.png``."""
    out.mkdir(parents=True, exist_ok=True)
    with (out / "compare.csv").open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["learner", "iteration", "tracking", "episode_length", "learning_rate"])
        for name, rows in runs.items():
            for r in rows:
                w.writerow(
                    [
                        name,
                        int(r["iteration"]),
                        r["tracking"],
                        r["episode_length"],
                        r.get("learning_rate", ""),
                    ]
                )
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(15, 4))
    panels = (
        ("tracking", "quad lin. velocity tracking (weighted, per env step)"),
        ("episode_length", "mean episode length (steps)"),
        ("learning_rate", "learning rate at the end of the iteration"),
    )
    for ax, (key, title) in zip(axes, panels, strict=True):
        for name, rows in runs.items():
            xs = [r["iteration"] for r in rows if key in r]
            ax.plot(xs, [r[key] for r in rows if key in r], label=name)
        ax.set_title(title)
        ax.set_xlabel("iteration")
        if key == "learning_rate":
            ax.set_yscale("log")
        ax.legend()
    fig.tight_layout()
    fig.savefig(out / "compare.png", dpi=90)
    plt.close(fig)
