"""unigait: client, vector envs and learner for the unigait Go2 simulation service.

Layout (split like rsl_rl): ``client`` (gRPC, numpy), ``env`` (torch vector env, history,
rsl_rl and Gymnasium adapters), ``storage`` (rollouts, GAE), ``algorithms`` (PPO, estimator),
``modules`` (networks), ``runners`` (training loop), ``utils`` (logging), ``export`` (ONNX),
``cli`` (``python -m unigait``). Only ``client`` is imported here, so the package works without
torch.
"""

from unigait.client import (
    Client,
    Session,
    SessionConfig,
    ShardedSession,
    Spec,
    StepResult,
    UnigaitError,
    open_session,
)

__version__ = "0.1.0"

__all__ = [
    "Client",
    "Session",
    "SessionConfig",
    "ShardedSession",
    "Spec",
    "StepResult",
    "UnigaitError",
    "__version__",
    "open_session",
]
