"""The explicit state estimator and the fused estimator + actor policy (the exported graph)."""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import nn

from unigait.modules.mlp import mlp


class Estimator(nn.Module):
    """MLP from the observation history to the estimated labels ê_t.

    Args:
        in_dim: History size (3 x 53 = 159).
        out_dim: Label size (14: base_lin_vel, foot_contact, terrain_normal, foot_height).
        hidden_dims: Hidden sizes ((256, 128) in the paper).
        activation: Activation name.
    """

    def __init__(
        self,
        in_dim: int,
        out_dim: int,
        hidden_dims: Sequence[int] = (256, 128),
        activation: str = "elu",
    ) -> None:
        super().__init__()
        self.net = mlp(in_dim, hidden_dims, out_dim, activation)

    def forward(self, history: torch.Tensor) -> torch.Tensor:
        """ê_t f32 [B, 14] from the flat history f32 [B, 159]."""
        return self.net(history)


class EstimatorActorPolicy(nn.Module):
    """Estimator and actor fused: o_{t-2:t} -> mean action (what the server runs).

    Args:
        estimator: The estimator.
        actor: The actor MLP (input: flat history then estimate).
    """

    def __init__(self, estimator: Estimator, actor: nn.Module) -> None:
        super().__init__()
        self.estimator = estimator
        self.actor = actor

    def forward(self, obs_history: torch.Tensor) -> torch.Tensor:
        """Actions f32 [B, 12] from ``obs_history`` f32 [B, 3, 53] (o_t, o_{t-1}, o_{t-2})."""
        flat = obs_history.flatten(1)
        return self.actor(torch.cat([flat, self.estimator(flat)], dim=-1))
