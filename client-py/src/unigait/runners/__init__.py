"""The training loop."""

from unigait.runners.on_policy_runner import (
    CheckpointMismatchError,
    NonFiniteUpdate,
    OnPolicyRunner,
    build_networks,
)
from unigait.runners.training import train

__all__ = [
    "CheckpointMismatchError",
    "NonFiniteUpdate",
    "OnPolicyRunner",
    "build_networks",
    "train",
]
