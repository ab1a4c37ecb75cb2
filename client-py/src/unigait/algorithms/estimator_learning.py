"""Supervised training of the estimator on the same rollouts as PPO (Ji et al. 2022)."""

from __future__ import annotations

from dataclasses import dataclass

from torch.nn import functional

from unigait.algorithms.optim import adam
from unigait.modules.estimator import Estimator
from unigait.storage.rollout_storage import RolloutStorage


@dataclass(frozen=True)
class EstimatorConfig:
    """Estimator hyper-parameters (Table III).

    Attributes:
        hidden_dims: Hidden sizes ((256, 128)).
        learning_rate: Adam learning rate (1e-4).
        mini_batch_size: Samples per step (768).
        num_epochs: Passes over the rollout per iteration (5).
    """

    hidden_dims: tuple[int, ...] = (256, 128)
    learning_rate: float = 1e-4
    mini_batch_size: int = 768
    num_epochs: int = 5


class EstimatorLearning:
    """MSE regression of ê_t on e_t from the stored histories.

    Args:
        estimator: The network.
        cfg: Hyper-parameters.
    """

    def __init__(self, estimator: Estimator, cfg: EstimatorConfig) -> None:
        self.estimator = estimator
        self.cfg = cfg
        self.optimizer = adam(estimator.parameters(), cfg.learning_rate)

    def update(self, storage: RolloutStorage) -> dict[str, float]:
        """Run the epochs; return the mean MSE."""
        total, count = 0.0, 0
        for history, labels in storage.estimator_batches(
            self.cfg.mini_batch_size, self.cfg.num_epochs
        ):
            loss = functional.mse_loss(self.estimator(history), labels)
            self.optimizer.zero_grad()
            loss.backward()
            self.optimizer.step()
            total += loss.item()
            count += 1
        return {"estimator_loss": total / max(count, 1)}
