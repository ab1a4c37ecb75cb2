"""Rollout buffer of T steps x N envs, GAE, and mini-batch iterators."""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass

import torch


def compute_gae(
    rewards: torch.Tensor,
    values: torch.Tensor,
    dones: torch.Tensor,
    last_values: torch.Tensor,
    gamma: float,
    lam: float,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Generalised advantage estimation over a rollout.

    ``dones[t]`` means the episode ended after step t: no value flows back across it. A time-out is
    handled by the caller, who adds ``gamma * V(final state)`` to ``rewards[t]`` and sets
    ``dones[t]``; a termination only sets ``dones[t]``.

    Args:
        rewards: f32 [T, N] rewards (truncation bootstrap already added).
        values: f32 [T, N] V(s_t) at action time.
        dones: bool or f32 [T, N].
        last_values: f32 [N] V(s_T) after the last step.
        gamma: Discount.
        lam: GAE lambda.

    Returns:
        advantages f32 [T, N] and returns f32 [T, N] (advantages + values).
    """
    steps = rewards.shape[0]
    not_done = 1.0 - dones.float()
    advantages = torch.zeros_like(rewards)
    gae = torch.zeros_like(last_values)
    for t in reversed(range(steps)):
        next_values = last_values if t == steps - 1 else values[t + 1]
        delta = rewards[t] + not_done[t] * gamma * next_values - values[t]
        gae = delta + not_done[t] * gamma * lam * gae
        advantages[t] = gae
    return advantages, advantages + values


def bootstrap_time_outs(
    rewards: torch.Tensor,
    terminated: torch.Tensor,
    truncated: torch.Tensor,
    final_env_ids: torch.Tensor,
    final_values: torch.Tensor,
    gamma: float,
) -> torch.Tensor:
    """Add gamma * V(final state) to the reward of envs that timed out (and did not terminate).

    Args:
        rewards: f32 [N] rewards of the step.
        terminated: bool [N].
        truncated: bool [N].
        final_env_ids: i64 [K] envs that ended in the step.
        final_values: f32 [K] critic values of their final critic inputs (o, e, s).
        gamma: Discount.

    Returns:
        f32 [N] new rewards (the input is not modified).
    """
    out = rewards.clone()
    if final_env_ids.numel():
        timed_out = (truncated & ~terminated)[final_env_ids]
        out[final_env_ids[timed_out]] += gamma * final_values[timed_out]
    return out


@dataclass
class MiniBatch:
    """A PPO mini-batch of B samples.

    Attributes:
        actor_obs: f32 [B, 173] history + estimate as the actor saw them.
        critic_obs: f32 [B, 77].
        actions: f32 [B, 12].
        old_log_prob: f32 [B].
        old_mu: f32 [B, 12].
        old_sigma: f32 [B, 12].
        old_values: f32 [B].
        advantages: f32 [B].
        returns: f32 [B].
    """

    actor_obs: torch.Tensor
    critic_obs: torch.Tensor
    actions: torch.Tensor
    old_log_prob: torch.Tensor
    old_mu: torch.Tensor
    old_sigma: torch.Tensor
    old_values: torch.Tensor
    advantages: torch.Tensor
    returns: torch.Tensor


class RolloutStorage:
    """Fixed-size buffer of one rollout.

    Every per-sample field the learners read is a column block of one ``[T, N, width]`` tensor
    (labels first, then the actor input, so the estimator's inputs are one leading block): an
    epoch's shuffle is then one row gather into a buffer kept between updates, and its
    mini-batches are row slices of that buffer, not nine fresh gathers per mini-batch.

    Args:
        num_steps: T steps per env.
        num_envs: N.
        actor_obs_dim: Actor input size (history + estimate, 173).
        history_dim: Estimator input size (the first ``history_dim`` columns of the actor input).
        critic_obs_dim: Critic input size (77).
        label_dim: Estimator target size (14).
        num_actions: 12.
        device: Where the buffer lives.
    """

    def __init__(
        self,
        num_steps: int,
        num_envs: int,
        actor_obs_dim: int,
        history_dim: int,
        critic_obs_dim: int,
        label_dim: int,
        num_actions: int,
        device: str | torch.device = "cpu",
    ) -> None:
        self.num_steps = num_steps
        self.num_envs = num_envs
        self.history_dim = history_dim
        self.label_dim = label_dim
        widths = {
            "labels": label_dim,
            "actor_obs": actor_obs_dim,
            "critic_obs": critic_obs_dim,
            "actions": num_actions,
            "mu": num_actions,
            "sigma": num_actions,
            "log_prob": 1,
            "values": 1,
            "advantages": 1,
            "returns": 1,
        }
        self._cols: dict[str, slice] = {}
        width = 0
        for name, w in widths.items():
            self._cols[name] = slice(width, width + w)
            width += w
        #: f32 [T, N, width]: every field below is a view of it.
        self.data = torch.zeros(num_steps, num_envs, width, device=device)
        self.labels = self.data[..., self._cols["labels"]]
        self.actor_obs = self.data[..., self._cols["actor_obs"]]
        self.critic_obs = self.data[..., self._cols["critic_obs"]]
        self.actions = self.data[..., self._cols["actions"]]
        self.mu = self.data[..., self._cols["mu"]]
        self.sigma = self.data[..., self._cols["sigma"]]
        self.log_prob = self.data[..., self._cols["log_prob"].start]
        self.values = self.data[..., self._cols["values"].start]
        self.advantages = self.data[..., self._cols["advantages"].start]
        self.returns = self.data[..., self._cols["returns"].start]
        self.rewards = torch.zeros(num_steps, num_envs, device=device)
        self.dones = torch.zeros(num_steps, num_envs, device=device)
        # Shuffled copies, allocated at the first update and refilled in place each epoch (a
        # fresh tensor of this size costs more in page faults than the gather itself).
        self._ppo_shuffled: torch.Tensor | None = None
        self._estimator_shuffled: torch.Tensor | None = None
        self.step = 0

    def add(
        self,
        actor_obs: torch.Tensor,
        critic_obs: torch.Tensor,
        labels: torch.Tensor,
        actions: torch.Tensor,
        log_prob: torch.Tensor,
        mu: torch.Tensor,
        sigma: torch.Tensor,
        values: torch.Tensor,
        rewards: torch.Tensor,
        dones: torch.Tensor,
    ) -> None:
        """Store step t (every argument is [N, ...] for this step).

        ``labels`` are e_t of the observation the actor acted on; ``dones`` mark episodes that
        ended after this step.
        """
        if self.step >= self.num_steps:
            raise OverflowError("rollout storage is full; call clear() first")
        t = self.step
        self.actor_obs[t] = actor_obs
        self.critic_obs[t] = critic_obs
        self.labels[t] = labels
        self.actions[t] = actions
        self.log_prob[t] = log_prob
        self.mu[t] = mu
        self.sigma[t] = sigma
        self.values[t] = values
        self.rewards[t] = rewards
        self.dones[t] = dones.float()
        self.step += 1

    def clear(self) -> None:
        """Start a new rollout."""
        self.step = 0

    def compute_returns(
        self, last_values: torch.Tensor, gamma: float, lam: float, normalize: bool = True
    ) -> None:
        """GAE over the stored rollout; advantages normalised over the whole batch if asked."""
        adv, returns = compute_gae(self.rewards, self.values, self.dones, last_values, gamma, lam)
        if normalize:
            adv = (adv - adv.mean()) / (adv.std() + 1e-8)
        self.returns.copy_(returns)
        self.advantages.copy_(adv)

    @staticmethod
    def _shuffle_into(
        buffer: torch.Tensor | None, source: torch.Tensor, perm: torch.Tensor
    ) -> torch.Tensor:
        """``source[perm]`` written into ``buffer`` (allocated when missing or of another size)."""
        if buffer is None or buffer.shape != source.shape:
            buffer = torch.empty_like(source, memory_format=torch.contiguous_format)
        return torch.index_select(source, 0, perm, out=buffer)

    def mini_batches(self, num_mini_batches: int, num_epochs: int) -> Iterator[MiniBatch]:
        """Random mini-batches over ``num_epochs`` passes (a fresh permutation per epoch).

        Mini-batch i of an epoch is the samples ``perm[i * B : (i + 1) * B]`` with
        ``B = T * N // num_mini_batches`` (samples past ``num_mini_batches * B`` sit the epoch
        out). Its tensors are views of a buffer that the next epoch's shuffle overwrites: use a
        mini-batch before asking for the one after it (PPO's loop does).
        """
        n = self.num_steps * self.num_envs
        size = n // num_mini_batches
        # Every column but the labels (the leading block), which PPO does not read.
        first = self._cols["actor_obs"].start
        source = self.data.view(n, -1)[:, first:]

        def cols(rows: torch.Tensor, name: str) -> torch.Tensor:
            c = self._cols[name]
            return rows[:, c.start - first : c.stop - first]

        def col(rows: torch.Tensor, name: str) -> torch.Tensor:
            return rows[:, self._cols[name].start - first]

        for _ in range(num_epochs):
            perm = torch.randperm(n, device=self.data.device)
            shuffled = self._shuffle_into(self._ppo_shuffled, source, perm)
            self._ppo_shuffled = shuffled
            for i in range(num_mini_batches):
                rows = shuffled[i * size : (i + 1) * size]
                yield MiniBatch(
                    actor_obs=cols(rows, "actor_obs"),
                    critic_obs=cols(rows, "critic_obs"),
                    actions=cols(rows, "actions"),
                    old_log_prob=col(rows, "log_prob"),
                    old_mu=cols(rows, "mu"),
                    old_sigma=cols(rows, "sigma"),
                    old_values=col(rows, "values"),
                    advantages=col(rows, "advantages"),
                    returns=col(rows, "returns"),
                )

    def estimator_batches(
        self, batch_size: int, num_epochs: int
    ) -> Iterator[tuple[torch.Tensor, torch.Tensor]]:
        """(history f32 [B, 159], labels f32 [B, 14]) mini-batches of ``batch_size`` samples.

        Batch k of an epoch is the samples ``perm[k * B : (k + 1) * B]``, as many whole batches
        as fit (one batch of every sample when there are fewer than ``batch_size``). The tensors
        are views of a buffer that the next epoch's shuffle overwrites, as in
        :meth:`mini_batches`.
        """
        n = self.num_steps * self.num_envs
        # Labels then the history: one leading column block.
        history_end = self._cols["actor_obs"].start + self.history_dim
        source = self.data.view(n, -1)[:, :history_end]
        for _ in range(num_epochs):
            perm = torch.randperm(n, device=self.data.device)
            shuffled = self._shuffle_into(self._estimator_shuffled, source, perm)
            self._estimator_shuffled = shuffled
            for start in range(0, n - batch_size + 1 if n >= batch_size else 1, batch_size):
                rows = shuffled[start : start + batch_size]
                yield rows[:, self.label_dim :], rows[:, : self.label_dim]

    def largest(self) -> dict[str, tuple[float, int, int, int]]:
        """Per field, the largest magnitude stored and where: (|value|, step, env, column).

        A non-finite entry counts as infinitely large (NaN included), so a rollout that would
        poison the update names its first bad field here rather than as a NaN loss.
        """
        fields = {
            "labels": self.labels,
            "actor_obs": self.actor_obs,
            "critic_obs": self.critic_obs,
            "actions": self.actions,
            "mu": self.mu,
            "values": self.values.unsqueeze(-1),
            "rewards": self.rewards.unsqueeze(-1),
        }
        out: dict[str, tuple[float, int, int, int]] = {}
        for name, x in fields.items():
            mag = x[: self.step].abs().nan_to_num(nan=math.inf, posinf=math.inf)
            if mag.numel() == 0:
                continue
            flat = int(torch.argmax(mag))
            t, rest = divmod(flat, mag.shape[1] * mag.shape[2])
            env, col = divmod(rest, mag.shape[2])
            out[name] = (float(mag.view(-1)[flat]), t, env, col)
        return out
