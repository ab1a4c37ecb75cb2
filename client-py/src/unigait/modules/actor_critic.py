"""Gaussian actor with a state-independent learned log-std, and a value critic."""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch
from torch import nn
from torch.distributions import Normal

from unigait.modules.mlp import mlp


class ActorCritic(nn.Module):
    """Actor (mean of a diagonal Gaussian) and critic (state value), separate MLPs.

    Args:
        actor_in: Actor input size (history 159 + estimate 14 = 173).
        critic_in: Critic input size (o_t 53 + e_t 14 + s_t 10 = 77).
        num_actions: 12.
        actor_hidden: Actor hidden sizes.
        critic_hidden: Critic hidden sizes.
        activation: Activation name.
        init_noise_std: Initial std of every action dimension. The network learns its logarithm
            (rsl_rl's "log" std type), so the std stays positive without a clamp that a step could
            pin it to, and a step changes it by a factor rather than by an amount.
    """

    def __init__(
        self,
        actor_in: int,
        critic_in: int,
        num_actions: int,
        actor_hidden: Sequence[int] = (512, 256, 128),
        critic_hidden: Sequence[int] = (512, 256, 128),
        activation: str = "elu",
        init_noise_std: float = 1.0,
    ) -> None:
        super().__init__()
        self.actor = mlp(actor_in, actor_hidden, num_actions, activation)
        self.critic = mlp(critic_in, critic_hidden, 1, activation)
        self.log_std = nn.Parameter(math.log(init_noise_std) * torch.ones(num_actions))

    @property
    def std(self) -> torch.Tensor:
        """f32 [12] the action std, exp(log_std)."""
        return self.log_std.exp()

    def distribution(self, actor_obs: torch.Tensor) -> Normal:
        """The action distribution for ``actor_obs`` f32 [B, actor_in]."""
        mean = self.actor(actor_obs)
        # Arguments are finite and the std positive by construction: skip torch's validation
        # pass over every sample of every mini-batch.
        return Normal(mean, self.std.expand_as(mean), validate_args=False)

    def act(self, actor_obs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, Normal]:
        """Sample actions.

        Returns:
            actions f32 [B, 12], their log-probability f32 [B], and the distribution.
        """
        dist = self.distribution(actor_obs)
        actions = dist.sample()
        return actions, dist.log_prob(actions).sum(-1), dist

    def act_inference(self, actor_obs: torch.Tensor) -> torch.Tensor:
        """The mean action f32 [B, 12]."""
        return self.actor(actor_obs)

    def value(self, critic_obs: torch.Tensor) -> torch.Tensor:
        """State value f32 [B] of ``critic_obs`` f32 [B, critic_in]."""
        return self.critic(critic_obs).squeeze(-1)
