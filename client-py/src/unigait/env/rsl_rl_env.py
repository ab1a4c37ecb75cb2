"""Adapter for rsl_rl's ``VecEnv`` (rsl_rl 5.x: TensorDict observations, 4-tuple step).

Observation groups:

* ``policy``: the 3-step history o_t, o_{t-1}, o_{t-2} flattened, f32 [N, 159] (the paper's actor
  input without the estimate; ``history_length=1`` gives o_t alone, [N, 53]). The adapter owns the
  history and refills it with the first observation of a new episode.
* ``critic``: o_t, e_t, s_t, f32 [N, 77].

Runner config (rsl_rl 5.x): ``obs_groups = {"actor": ["policy"], "critic": ["critic"]}``; see
:func:`rsl_rl_train_cfg`. ``extras["time_outs"]`` marks time-outs (rsl_rl bootstraps them with the
value at action time), ``extras["log"]`` holds ``Episode_Reward/<term>`` (episode sum divided by the
longest episode in seconds, as Isaac Lab logs it) for the episodes that ended in the step.
"""

from __future__ import annotations

from typing import Any

import torch
from rsl_rl.env import VecEnv
from tensordict import TensorDict

from unigait.env.episode_stats import EpisodeStats
from unigait.env.history import ObservationHistory
from unigait.env.torch_env import TorchStep, TorchVecEnv


class RslRlVecEnv(VecEnv):
    """rsl_rl ``VecEnv`` over a :class:`TorchVecEnv`.

    Args:
        env: The torch env (its session must return reward terms for the per-term logs).
        history_length: Observations stacked in the ``policy`` group (3: the paper's history).

    Attributes:
        num_envs: N.
        num_actions: 12.
        max_episode_length: Policy steps of the longest episode (900).
        episode_length_buf: i64 [N] steps into the current episode. The server owns the real
            episode clock, so writing this buffer (``init_at_random_ep_len``) changes nothing.
        device: Device of the tensors.
        cfg: Session and spec summary (stored by rsl_rl's logger).
    """

    def __init__(self, env: TorchVecEnv, history_length: int = 3) -> None:
        self.env = env
        self.spec = env.spec
        self.num_envs = env.num_envs
        self.num_actions = env.num_actions
        self.max_episode_length = self.spec.max_episode_steps
        self.device = env.device
        self.episode_length_buf = torch.zeros(self.num_envs, dtype=torch.int64, device=self.device)
        self.history = ObservationHistory(
            self.num_envs, history_length, self.spec.obs_dim, self.device
        )
        self.history.reset(env.last.obs)
        self.stats = EpisodeStats(self.num_envs, self.spec.reward_terms, self.device)
        self.cfg: dict[str, Any] = {
            "num_envs": self.num_envs,
            "history_length": history_length,
            "policy_dt": self.spec.policy_dt,
            "max_episode_steps": self.spec.max_episode_steps,
            "reward_terms": list(self.spec.reward_terms),
            "task_config_toml": self.spec.task_config_toml,
            "terrain": self.spec.terrain,
            "server_version": self.spec.server_version,
        }

    def _observations(self, step: TorchStep) -> TensorDict:
        return TensorDict(
            {"policy": self.history.flat, "critic": step.critic_obs},
            batch_size=[self.num_envs],
            device=self.device,
        )

    def get_observations(self) -> TensorDict:
        """Current observations: ``policy`` f32 [N, 53 H] and ``critic`` f32 [N, 77]."""
        return self._observations(self.env.last)

    def reset(self) -> tuple[TensorDict, dict]:
        """Reset every env."""
        step = self.env.reset()
        self.history.reset(step.obs)
        self.episode_length_buf.zero_()
        self.stats = EpisodeStats(self.num_envs, self.spec.reward_terms, self.device)
        return self._observations(step), {}

    def step(self, actions: torch.Tensor) -> tuple[TensorDict, torch.Tensor, torch.Tensor, dict]:
        """Step every env.

        Args:
            actions: f32 [N, 12].

        Returns:
            Observations (TensorDict), rewards f32 [N], dones i64 [N] and extras with
            ``time_outs`` (bool [N]) and ``log`` (scalars by name).
        """
        step = self.env.step(actions)
        dones = step.dones
        self.history.push(step.obs, dones)
        self.episode_length_buf += 1
        self.episode_length_buf[dones] = 0
        ended = self.stats.update(step)
        log: dict[str, Any] = {}
        k = int(ended["reward"].numel())
        if k:
            per_s = ended["terms"].mean(dim=0) / self.spec.episode_length_s
            for i, name in enumerate(self.spec.reward_terms):
                log[f"Episode_Reward/{name}"] = per_s[i]
            log["Episode_Termination/time_out"] = float(ended["time_out"].sum())
            log["Episode_Termination/base_contact"] = float(k - ended["time_out"].sum())
        log["Curriculum/terrain_level"] = step.terrain_level.float().mean()
        log["Metrics/biped_share"] = (step.mode == 1).float().mean()
        extras = {"time_outs": step.truncated & ~step.terminated, "log": log}
        return self._observations(step), step.reward, dones.long(), extras

    def close(self) -> None:
        """Close the session."""
        self.env.close()


def rsl_rl_train_cfg(
    num_steps_per_env: int = 24,
    hidden_dims: tuple[int, ...] = (512, 256, 128),
    save_interval: int = 50,
    logger: str = "tensorboard",
) -> dict[str, Any]:
    """A train config for rsl_rl 5.x's ``OnPolicyRunner`` with the paper's PPO settings.

    The actor sees the ``policy`` group (history), the critic the ``critic`` group.
    """
    return {
        "num_steps_per_env": num_steps_per_env,
        "save_interval": save_interval,
        "obs_groups": {"actor": ["policy"], "critic": ["critic"]},
        "logger": logger,
        "check_for_nan": True,
        "actor": {
            "class_name": "MLPModel",
            "hidden_dims": list(hidden_dims),
            "activation": "elu",
            "obs_normalization": False,
            "distribution_cfg": {
                "class_name": "GaussianDistribution",
                "init_std": 1.0,
                "std_type": "scalar",
            },
        },
        "critic": {
            "class_name": "MLPModel",
            "hidden_dims": list(hidden_dims),
            "activation": "elu",
            "obs_normalization": False,
        },
        "algorithm": {
            "class_name": "PPO",
            "num_learning_epochs": 5,
            "num_mini_batches": 4,
            "clip_param": 0.2,
            "gamma": 0.99,
            "lam": 0.95,
            "value_loss_coef": 1.0,
            "entropy_coef": 0.01,
            "learning_rate": 1e-3,
            "max_grad_norm": 1.0,
            "use_clipped_value_loss": True,
            "schedule": "adaptive",
            "desired_kl": 0.01,
        },
    }
