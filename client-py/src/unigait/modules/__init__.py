"""Networks: MLP builder, actor-critic, estimator and the fused export policy."""

from unigait.modules.actor_critic import ActorCritic
from unigait.modules.estimator import Estimator, EstimatorActorPolicy
from unigait.modules.mlp import mlp

__all__ = ["ActorCritic", "Estimator", "EstimatorActorPolicy", "mlp"]
