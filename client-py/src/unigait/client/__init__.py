"""gRPC client of the unigait simulation service.

Example:
    >>> from unigait.client import SessionConfig, open_session  # doctest: +SKIP
    >>> with open_session("127.0.0.1:50051", SessionConfig(num_envs=64)) as s:  # doctest: +SKIP
    ...     clock = s.initial.obs[:, s.spec.obs.slice("clock")]  # f32 [64, 4]
"""

from unigait.client.connection import ConnectionOptions, load_connection_options, parse_address
from unigait.client.errors import ProtocolError, UnigaitError
from unigait.client.session import DEFAULT_MAX_MESSAGE_BYTES, Client, Session
from unigait.client.sharded import SessionLike, ShardedSession, open_session, split_envs
from unigait.client.spec import FieldSpec, Spec, TensorSpec
from unigait.client.types import EvaluateResult, ServerInfo, SessionConfig, StepResult

__all__ = [
    "DEFAULT_MAX_MESSAGE_BYTES",
    "Client",
    "ConnectionOptions",
    "EvaluateResult",
    "FieldSpec",
    "ProtocolError",
    "ServerInfo",
    "Session",
    "SessionConfig",
    "SessionLike",
    "ShardedSession",
    "Spec",
    "StepResult",
    "TensorSpec",
    "UnigaitError",
    "load_connection_options",
    "open_session",
    "parse_address",
    "split_envs",
]
