"""The training loop."""

from unigait.runners.on_policy_runner import OnPolicyRunner, build_networks

__all__ = ["OnPolicyRunner", "build_networks"]
