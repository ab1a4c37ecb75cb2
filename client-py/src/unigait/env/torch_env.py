"""Torch vector env over a unigait session: batched tensors on a chosen device."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from functools import cached_property

import numpy as np
import torch

from unigait.client import SessionConfig, SessionLike, Spec, StepResult, open_session


def _t(array: np.ndarray, device: torch.device, dtype: torch.dtype | None = None) -> torch.Tensor:
    # The reply's buffers are read-only; torch.tensor copies (one memcpy per tensor).
    return torch.tensor(array, dtype=dtype, device=device)


@dataclass
class TorchStep:
    """One batched step as torch tensors (N envs, K of them ended in this step).

    Attributes:
        obs: f32 [N, 53] o_t after autoreset.
        labels: f32 [N, 14] e_t.
        privileged: f32 [N, 10] s_t.
        reward: f32 [N] total reward.
        reward_terms: f32 [N, T] weighted reward per term (T = len(spec.reward_terms)), or None.
        terminated: bool [N] ended by a trunk contact (not bootstrapped).
        truncated: bool [N] ended by time-out (bootstrapped from the final critic input).
        final_env_ids: int64 [K] envs that ended.
        final_obs: f32 [K, 53] last o_t of the ended episodes.
        final_labels: f32 [K, 14] last e_t of the ended episodes.
        final_privileged: f32 [K, 10] s_t of the ended episodes.
        final_episode_length: int64 [K] length in steps of the ended episodes.
        mode: int64 [N] task mode for the next action (1 biped, 2 quad).
        terrain_level: int64 [N] terrain level.
        head_contact: bool [N] the head touched the terrain in this step (None when the server
            does not report it).
        upright_pitch: the upright indicator's threshold from the next step on (rad; None when
            the server does not report it).
        nonfinite_resets: envs the server reset after a physics blow-up in this step.
        mode_levels: int64 [N, 2] each env's own (quad, biped) levels (None from older servers).
    """

    obs: torch.Tensor
    labels: torch.Tensor
    privileged: torch.Tensor
    reward: torch.Tensor
    reward_terms: torch.Tensor | None
    terminated: torch.Tensor
    truncated: torch.Tensor
    final_env_ids: torch.Tensor
    final_obs: torch.Tensor
    final_labels: torch.Tensor
    final_privileged: torch.Tensor
    final_episode_length: torch.Tensor
    mode: torch.Tensor
    terrain_level: torch.Tensor
    head_contact: torch.Tensor | None = None
    upright_pitch: float | None = None
    nonfinite_resets: int = 0
    mode_levels: torch.Tensor | None = None
    #: f32 [K, B, 7] poses of the envs the step named in ``draw_envs`` (numpy: for drawing).
    body_poses: np.ndarray | None = None

    @property
    def dones(self) -> torch.Tensor:
        """bool [N]: terminated or truncated."""
        return self.terminated | self.truncated

    @cached_property
    def critic_obs(self) -> torch.Tensor:
        """f32 [N, 77]: o_t, e_t, s_t (the critic's input), built once per step."""
        return torch.cat([self.obs, self.labels, self.privileged], dim=-1)

    @property
    def final_critic_obs(self) -> torch.Tensor:
        """f32 [K, 77]: the critic input of the ended episodes' last state."""
        return torch.cat([self.final_obs, self.final_labels, self.final_privileged], dim=-1)

    @classmethod
    def from_result(cls, r: StepResult, device: torch.device) -> TorchStep:
        """Convert a numpy :class:`StepResult`."""
        return cls(
            obs=_t(r.obs, device),
            labels=_t(r.labels, device),
            privileged=_t(r.privileged, device),
            reward=_t(r.reward, device),
            reward_terms=None if r.reward_terms is None else _t(r.reward_terms, device),
            terminated=_t(r.terminated, device),
            truncated=_t(r.truncated, device),
            final_env_ids=_t(r.final_env_ids, device, torch.int64),
            final_obs=_t(r.final_obs, device),
            final_labels=_t(r.final_labels, device),
            final_privileged=_t(r.final_privileged, device),
            final_episode_length=_t(r.final_episode_length, device, torch.int64),
            mode=_t(r.mode, device, torch.int64),
            terrain_level=_t(r.terrain_level, device, torch.int64),
            head_contact=None if r.head_contact is None else _t(r.head_contact, device),
            upright_pitch=r.upright_pitch,
            nonfinite_resets=r.nonfinite_resets,
            mode_levels=None if r.mode_levels is None else _t(r.mode_levels, device, torch.int64),
            body_poses=r.body_poses,
        )


class TorchVecEnv:
    """A session (one server or sharded) seen as a batched torch env.

    Args:
        session: An open session; the env closes it in :meth:`close`.
        device: Where the tensors live.

    Attributes:
        spec: The session spec (slices by name: ``env.spec.obs.slice("clock")``).
        num_envs: N.
        num_actions: 12.
        last: The most recent step (or the initial reset).
    """

    def __init__(self, session: SessionLike, device: str | torch.device = "cpu") -> None:
        self.session = session
        self.device = torch.device(device)
        self.spec: Spec = session.spec
        self.num_envs = self.spec.num_envs
        self.num_actions = self.spec.num_actions
        self.last = TorchStep.from_result(session.initial, self.device)

    @classmethod
    def connect(
        cls, addresses: str | list[str], config: SessionConfig, device: str | torch.device = "cpu"
    ) -> TorchVecEnv:
        """Open a session on one or several servers (sharded) and wrap it."""
        return cls(open_session(addresses, config), device)

    def step(self, actions: torch.Tensor, draw_envs: Sequence[int] = ()) -> TorchStep:
        """Step every env.

        Args:
            actions: f32 [N, 12] on any device.
            draw_envs: Envs whose body poses the step returns (``body_poses``), for a live view.

        Returns:
            The step; ended envs are already reset (``obs`` is their new first observation).
        """
        a = actions.detach().to("cpu", torch.float32).numpy()
        result = self.session.step(a, draw_envs=draw_envs) if draw_envs else self.session.step(a)
        self.last = TorchStep.from_result(result, self.device)
        return self.last

    def reset(self, mask: torch.Tensor | None = None) -> TorchStep:
        """Reset all envs, or where ``mask`` (bool [N]) is set.

        Note:
            Only the reset rows of the returned step are new observations.
        """
        m = None if mask is None else mask.detach().to("cpu").numpy()
        self.last = TorchStep.from_result(self.session.reset(m), self.device)
        return self.last

    def close(self) -> None:
        """Close the session."""
        self.session.close()
