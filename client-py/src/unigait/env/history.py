"""Observation history o_{t-H+1:t}, owned by the learner (the service sends o_t only)."""

from __future__ import annotations

import torch


class ObservationHistory:
    """The last ``length`` observations per env, newest first.

    ``buffer[:, 0]`` is o_t, ``buffer[:, 1]`` is o_{t-1}, ... An env that resets gets its whole
    history filled with its new first observation.

    Args:
        num_envs: N.
        length: H (3 in the paper).
        obs_dim: D (53).
        device: Where the buffer lives.
    """

    def __init__(
        self, num_envs: int, length: int, obs_dim: int, device: str | torch.device = "cpu"
    ) -> None:
        self.length = length
        self.buffer = torch.zeros(num_envs, length, obs_dim, device=device)

    def reset(self, obs: torch.Tensor, mask: torch.Tensor | None = None) -> None:
        """Fill the history of every env (or where bool [N] ``mask`` is set) with ``obs`` [N, D]."""
        if mask is None:
            self.buffer[:] = obs.unsqueeze(1)
        else:
            self.buffer[mask] = obs[mask].unsqueeze(1).expand(-1, self.length, -1)

    def push(self, obs: torch.Tensor, reset: torch.Tensor | None = None) -> None:
        """Append o_t f32 [N, D]; envs in ``reset`` (bool [N]) start a fresh history with it."""
        self.buffer = torch.cat([obs.unsqueeze(1), self.buffer[:, :-1]], dim=1)
        if reset is not None and bool(reset.any()):
            self.reset(obs, reset)

    @property
    def flat(self) -> torch.Tensor:
        """f32 [N, H * D]: o_t, o_{t-1}, ... concatenated."""
        return self.buffer.flatten(1)
