"""Per-env episode bookkeeping: running reward sums per term, logged when episodes end."""

from __future__ import annotations

import torch

from unigait.env.torch_env import TorchStep


class EpisodeStats:
    """Running sums of the total reward and of every reward term, per env.

    Args:
        num_envs: N.
        term_names: Names of the reward terms (columns of ``reward_terms``).
        device: Where the sums live.
    """

    def __init__(self, num_envs: int, term_names: tuple[str, ...], device: torch.device) -> None:
        self.term_names = term_names
        self.reward_sum = torch.zeros(num_envs, device=device)
        self.term_sums = torch.zeros(num_envs, len(term_names), device=device)
        self.length = torch.zeros(num_envs, dtype=torch.int64, device=device)

    def update(self, step: TorchStep) -> dict[str, torch.Tensor]:
        """Add one step; return the totals of the episodes that ended in it.

        Returns:
            ``{"reward": f32 [K], "length": i64 [K], "terms": f32 [K, 26], "time_out": bool [K]}``
            for the K envs that ended (empty tensors when none did).
        """
        self.reward_sum += step.reward
        if step.reward_terms is not None:
            self.term_sums += step.reward_terms
        self.length += 1
        done = step.dones
        ended = {
            "reward": self.reward_sum[done].clone(),
            "length": self.length[done].clone(),
            "terms": self.term_sums[done].clone(),
            "time_out": (step.truncated & ~step.terminated)[done],
        }
        self.reward_sum[done] = 0.0
        self.term_sums[done] = 0.0
        self.length[done] = 0
        return ended
