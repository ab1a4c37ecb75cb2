"""PPO with clipped value loss and the adaptive learning-rate rule (rsl_rl's defaults)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import nn

from unigait.algorithms.optim import adam
from unigait.algorithms.symmetry import ActorMirror, mirror_loss
from unigait.modules.actor_critic import ActorCritic
from unigait.storage.rollout_storage import RolloutStorage


@dataclass(frozen=True)
class PPOConfig:
    """PPO hyper-parameters (Table III of the paper, rsl_rl's defaults otherwise).

    Attributes:
        num_learning_epochs: Passes over the rollout per update (5).
        num_mini_batches: Mini-batches per pass (4).
        clip_param: Ratio and value clip (0.2).
        gamma: Discount (0.99).
        lam: GAE lambda (0.95).
        value_loss_coef: Weight of the value loss (1.0).
        entropy_coef: Weight of the entropy bonus (0.01).
        learning_rate: Initial Adam learning rate (1e-3).
        max_grad_norm: Gradient norm clip (1.0).
        use_clipped_value_loss: Clip the value update like the ratio (True).
        schedule: ``"adaptive"`` (KL-driven) or ``"fixed"``.
        desired_kl: Target KL of the adaptive schedule (0.01).
        normalize_advantage: Normalise advantages over the batch (True).
        min_action_std: Floor of every action dim's std, applied after each Adam step (0: none).
            The biped-only baseline's stage 1 needs it: alone, its std fell from 1.0 to 0.37 and
            exploration with it (docs/src/decisions/0028-action-std-floor.md).
        action_mean_bound: |mean action| past which the bound loss pays (0: no bound loss).
        bound_loss_coef: Weight of the bound loss, sum_i max(|mu_i| - bound, 0)^2 averaged over
            the batch (rl_games' bounds loss). A Gaussian's mean is otherwise unbounded: on
            stairs the terrain run's means reached 100-155 (targets 25-39 rad from default) and
            its updates went non-finite (docs/src/decisions/0031-action-mean-bound.md).
        mirror_loss_coef: Weight of the mirror loss, mean (mu(M x) - M mu(x))^2 with M the
            robot's left-right mirror (0: none). It needs the mirror maps, which the runner
            builds from the session spec (docs/src/decisions/0033-mirror-loss.md).
    """

    num_learning_epochs: int = 5
    num_mini_batches: int = 4
    clip_param: float = 0.2
    gamma: float = 0.99
    lam: float = 0.95
    value_loss_coef: float = 1.0
    entropy_coef: float = 0.01
    learning_rate: float = 1e-3
    max_grad_norm: float = 1.0
    use_clipped_value_loss: bool = True
    schedule: str = "adaptive"
    desired_kl: float = 0.01
    normalize_advantage: bool = True
    min_action_std: float = 0.0
    action_mean_bound: float = 0.0
    bound_loss_coef: float = 0.0
    mirror_loss_coef: float = 0.0


def gaussian_kl(
    mu_old: torch.Tensor, sigma_old: torch.Tensor, mu_new: torch.Tensor, sigma_new: torch.Tensor
) -> torch.Tensor:
    """KL(old || new) of diagonal Gaussians, summed over the action dims.

    KL = sum_i ln(s_new / s_old + 1e-5) + (s_old^2 + (mu_old - mu_new)^2) / (2 s_new^2) - 0.5,
    as rsl_rl computes it.

    Args:
        mu_old: f32 [B, A].
        sigma_old: f32 [B, A].
        mu_new: f32 [B, A].
        sigma_new: f32 [B, A].

    Returns:
        f32 [B].
    """
    return torch.sum(
        torch.log(sigma_new / sigma_old + 1.0e-5)
        + (sigma_old.square() + (mu_old - mu_new).square()) / (2.0 * sigma_new.square())
        - 0.5,
        dim=-1,
    )


def bound_loss(mu: torch.Tensor, bound: float) -> torch.Tensor:
    """Mean over the batch of sum_i max(|mu_i| - bound, 0)^2 (zero inside the bound).

    Args:
        mu: f32 [B, A] mean actions.
        bound: The soft bound (> 0).

    Returns:
        f32 scalar.
    """
    return (mu.abs() - bound).clamp(min=0.0).square().sum(-1).mean()


def adaptive_learning_rate(
    lr: float, kl: float, desired_kl: float, min_lr: float = 1e-5, max_lr: float = 1e-2
) -> float:
    """rsl_rl's adaptive rule: shrink by 1.5 when KL > 2 kl*, grow by 1.5 when 0 < KL < kl*/2.

    Args:
        lr: Current learning rate.
        kl: Mean KL of the mini-batch.
        desired_kl: Target kl*.
        min_lr: Floor (1e-5).
        max_lr: Ceiling (1e-2).
    """
    if kl > 2.0 * desired_kl:
        return max(min_lr, lr / 1.5)
    if 0.0 < kl < desired_kl / 2.0:
        return min(max_lr, lr * 1.5)
    return lr


class PPO:
    """The PPO update over a :class:`RolloutStorage`.

    Args:
        actor_critic: The networks (one Adam optimiser over actor, critic and std).
        cfg: Hyper-parameters.
        mirror: The left-right mirror of the actor's input and actions; needed when
            ``cfg.mirror_loss_coef`` > 0.

    Raises:
        ValueError: A mirror loss weight without the mirror maps.
    """

    def __init__(
        self, actor_critic: ActorCritic, cfg: PPOConfig, mirror: ActorMirror | None = None
    ) -> None:
        if cfg.mirror_loss_coef > 0.0 and mirror is None:
            raise ValueError("ppo.mirror_loss_coef > 0 needs the mirror maps (ActorMirror)")
        self.actor_critic = actor_critic
        self.cfg = cfg
        self.mirror = mirror if cfg.mirror_loss_coef > 0.0 else None
        self.learning_rate = cfg.learning_rate
        self.optimizer = adam(actor_critic.parameters(), cfg.learning_rate)

    def _set_lr(self, lr: float) -> None:
        self.learning_rate = lr
        for group in self.optimizer.param_groups:
            group["lr"] = lr

    def update(self, storage: RolloutStorage) -> dict[str, float]:
        """Run the epochs; return mean losses, mean KL and the final learning rate."""
        cfg = self.cfg
        ac = self.actor_critic
        sums = {
            "value_loss": 0.0,
            "surrogate_loss": 0.0,
            "entropy": 0.0,
            "kl": 0.0,
            "bound_loss": 0.0,
            "mirror_loss": 0.0,
        }
        bounded = cfg.action_mean_bound > 0.0 and cfg.bound_loss_coef > 0.0
        count = 0
        for mb in storage.mini_batches(cfg.num_mini_batches, cfg.num_learning_epochs):
            dist = ac.distribution(mb.actor_obs)
            log_prob = dist.log_prob(mb.actions).sum(-1)
            entropy = dist.entropy().sum(-1)
            values = ac.value(mb.critic_obs)

            with torch.no_grad():
                kl = gaussian_kl(mb.old_mu, mb.old_sigma, dist.mean, dist.stddev).mean().item()
            if cfg.schedule == "adaptive" and cfg.desired_kl > 0.0:
                self._set_lr(adaptive_learning_rate(self.learning_rate, kl, cfg.desired_kl))

            ratio = torch.exp(log_prob - mb.old_log_prob)
            surrogate = -mb.advantages * ratio
            surrogate_clipped = -mb.advantages * torch.clamp(
                ratio, 1.0 - cfg.clip_param, 1.0 + cfg.clip_param
            )
            surrogate_loss = torch.max(surrogate, surrogate_clipped).mean()

            if cfg.use_clipped_value_loss:
                v_clipped = mb.old_values + (values - mb.old_values).clamp(
                    -cfg.clip_param, cfg.clip_param
                )
                value_loss = torch.max(
                    (values - mb.returns).square(), (v_clipped - mb.returns).square()
                ).mean()
            else:
                value_loss = (values - mb.returns).square().mean()

            loss = (
                surrogate_loss
                + cfg.value_loss_coef * value_loss
                - cfg.entropy_coef * entropy.mean()
            )
            if bounded:
                b_loss = bound_loss(dist.mean, cfg.action_mean_bound)
                loss = loss + cfg.bound_loss_coef * b_loss
                sums["bound_loss"] += b_loss.item()
            if self.mirror is not None:
                mirrored = ac.act_inference(self.mirror.actor_obs(mb.actor_obs))
                m_loss = mirror_loss(dist.mean, mirrored, self.mirror)
                loss = loss + cfg.mirror_loss_coef * m_loss
                sums["mirror_loss"] += m_loss.item()
            self.optimizer.zero_grad()
            loss.backward()
            nn.utils.clip_grad_norm_(ac.parameters(), cfg.max_grad_norm)
            self.optimizer.step()
            if cfg.min_action_std > 0.0:
                with torch.no_grad():
                    ac.log_std.clamp_(min=math.log(cfg.min_action_std))

            sums["value_loss"] += value_loss.item()
            sums["surrogate_loss"] += surrogate_loss.item()
            sums["entropy"] += entropy.mean().item()
            sums["kl"] += kl
            count += 1
        stats = {k: v / max(count, 1) for k, v in sums.items()}
        if not bounded:
            del stats["bound_loss"]
        if self.mirror is None:
            del stats["mirror_loss"]
        stats["learning_rate"] = self.learning_rate
        stats["action_std"] = ac.std.mean().item()
        return stats
