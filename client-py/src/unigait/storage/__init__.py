"""Rollout storage and GAE."""

from unigait.storage.rollout_storage import (
    MiniBatch,
    RolloutStorage,
    bootstrap_time_outs,
    compute_gae,
)

__all__ = ["MiniBatch", "RolloutStorage", "bootstrap_time_outs", "compute_gae"]
