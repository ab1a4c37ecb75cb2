"""Gymnasium 1.x ``VectorEnv`` over a unigait session (numpy arrays, same-step autoreset).

Observations are o_t, f32 [N, 53]; actions f32 [N, 12] (joint target = default + 0.25 action,
clipped to +-100 by the server). ``info`` carries ``labels`` [N, 14], ``privileged`` [N, 10],
``reward_terms`` [N, T] (the spec's T terms), ``mode`` [N] and ``terrain_level`` [N]; for envs
that ended in the step, ``info["final_obs"]`` (object array, an f32 [53] row where
``info["_final_obs"]`` is set) and ``info["final_info"]`` (``labels``, ``privileged``,
``episode_length``) hold the last values of the ended episode, as Gymnasium's same-step
autoreset prescribes.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium.vector import AutoresetMode, VectorEnv

from unigait.client import SessionConfig, SessionLike, StepResult, open_session


class UnigaitVectorEnv(VectorEnv):
    """A Gymnasium vector env whose sub-envs run on one or several unigait servers.

    Args:
        addresses: Server address(es); several shard the batch.
        config: Session config (``num_envs`` is N; ``seed`` the default seed).
        session_factory: Opens a session for a config (default: :func:`open_session` on
            ``addresses``); lets tests and custom transports plug in.

    ``reset(seed=s)`` with a new seed re-creates the session with that seed (the server draws
    every random value from the session seed); ``reset(options={"mask": m})`` resets only the
    envs where the bool [N] mask is set.
    """

    metadata: dict[str, Any] = {"autoreset_mode": AutoresetMode.SAME_STEP, "render_modes": []}  # noqa: RUF012

    def __init__(
        self,
        addresses: str | list[str],
        config: SessionConfig,
        session_factory: Callable[[SessionConfig], SessionLike] | None = None,
    ) -> None:
        self._open: Callable[[SessionConfig], SessionLike] = session_factory or (
            lambda cfg: open_session(addresses, cfg)
        )
        self._config = config
        self._session: SessionLike = self._open(config)
        spec = self._session.spec
        self.spec_unigait = spec
        self.num_envs = spec.num_envs
        self.single_observation_space = gym.spaces.Box(
            -np.inf, np.inf, (spec.obs_dim,), dtype=np.float32
        )
        self.single_action_space = gym.spaces.Box(
            -100.0, 100.0, (spec.num_actions,), dtype=np.float32
        )
        self.observation_space = gym.vector.utils.batch_space(
            self.single_observation_space, self.num_envs
        )
        self.action_space = gym.vector.utils.batch_space(self.single_action_space, self.num_envs)
        self._pending_initial: StepResult | None = self._session.initial

    def _info(self, r: StepResult) -> dict[str, Any]:
        n = self.num_envs
        everywhere = np.ones(n, dtype=bool)
        info: dict[str, Any] = {
            "labels": np.array(r.labels),
            "_labels": everywhere,
            "privileged": np.array(r.privileged),
            "_privileged": everywhere,
            "mode": np.array(r.mode),
            "_mode": everywhere,
            "terrain_level": np.array(r.terrain_level),
            "_terrain_level": everywhere,
        }
        if r.reward_terms is not None:
            info["reward_terms"] = np.array(r.reward_terms)
            info["_reward_terms"] = everywhere
        return info

    def reset(
        self, *, seed: int | list[int] | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        """Reset every env (or ``options["mask"]``); returns o_t f32 [N, 53] and info."""
        if isinstance(seed, list):
            seed = seed[0]
        super().reset(seed=seed)
        if seed is not None and seed != self._config.seed:
            self._session.close()
            self._config = dataclasses.replace(self._config, seed=int(seed))
            self._session = self._open(self._config)
            self._pending_initial = self._session.initial
        mask = None if options is None else options.get("mask")
        if self._pending_initial is not None and mask is None:
            r = self._pending_initial
        else:
            r = self._session.reset(mask)
        self._pending_initial = None
        return np.array(r.obs), self._info(r)

    def step(
        self, actions: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
        """Step every env with ``actions`` f32 [N, 12].

        Returns:
            obs f32 [N, 53], reward f32 [N], terminated bool [N], truncated bool [N], info.
        """
        self._pending_initial = None
        r = self._session.step(np.asarray(actions, dtype=np.float32))
        info = self._info(r)
        if r.final_env_ids.size:
            n = self.num_envs
            ids = r.final_env_ids
            ended = np.zeros(n, dtype=bool)
            ended[ids] = True
            final_obs = np.full(n, None, dtype=object)
            for k, env in enumerate(ids):
                final_obs[env] = np.array(r.final_obs[k])
            labels = np.zeros((n, r.final_labels.shape[1]), dtype=np.float32)
            labels[ids] = r.final_labels
            privileged = np.zeros((n, r.final_privileged.shape[1]), dtype=np.float32)
            privileged[ids] = r.final_privileged
            length = np.zeros(n, dtype=np.int64)
            length[ids] = r.final_episode_length
            info["final_obs"] = final_obs
            info["_final_obs"] = ended
            info["final_info"] = {
                "labels": labels,
                "_labels": ended,
                "privileged": privileged,
                "_privileged": ended,
                "episode_length": length,
                "_episode_length": ended,
            }
            info["_final_info"] = ended
        return (
            np.array(r.obs),
            np.array(r.reward),
            np.array(r.terminated),
            np.array(r.truncated),
            info,
        )

    def close_extras(self, **kwargs: Any) -> None:
        """Close the session."""
        self._session.close()
