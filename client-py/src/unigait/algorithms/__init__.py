"""Learning algorithms: PPO and the concurrent estimator regression."""

from unigait.algorithms.estimator_learning import EstimatorConfig, EstimatorLearning
from unigait.algorithms.ppo import (
    PPO,
    PPOConfig,
    adaptive_learning_rate,
    bound_loss,
    gaussian_kl,
)

__all__ = [
    "PPO",
    "EstimatorConfig",
    "EstimatorLearning",
    "PPOConfig",
    "adaptive_learning_rate",
    "bound_loss",
    "gaussian_kl",
]
