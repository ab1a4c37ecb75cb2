"""Exceptions raised by the client."""

from __future__ import annotations

from collections.abc import Callable
from typing import TypeVar

import grpc

T = TypeVar("T")

#: Appended to the server's message when it refuses a call for want of the right token.
UNAUTHENTICATED_HINT = (
    "the server wants its bearer token: Client(..., token=...), open_session(..., token=...), "
    "or on the command line --token-file FILE or $UNIGAIT_TOKEN"
)


class UnigaitError(Exception):
    """A failed call to the server, carrying the gRPC status.

    Attributes:
        code: The gRPC status code.
        code_name: The status code's name, e.g. ``"INVALID_ARGUMENT"`` or ``"NOT_FOUND"``.
        details: The server's message.
    """

    def __init__(self, code: grpc.StatusCode, details: str) -> None:
        self.code = code
        self.code_name: str = code.name
        self.details = details
        super().__init__(f"{self.code_name}: {details}")

    @classmethod
    def from_rpc_error(cls, err: grpc.RpcError) -> UnigaitError:
        """Build from a grpc error (a ``grpc.Call`` in practice)."""
        code = err.code() if isinstance(err, grpc.Call) else grpc.StatusCode.UNKNOWN
        details = (err.details() if isinstance(err, grpc.Call) else None) or str(err)
        if code == grpc.StatusCode.UNAUTHENTICATED:
            details += f" ({UNAUTHENTICATED_HINT})"
        return cls(code, details)


class ProtocolError(Exception):
    """The server sent something that does not match the protocol (e.g. a bad tensor size)."""


def call(fn: Callable[[], T]) -> T:
    """Run ``fn`` and turn a ``grpc.RpcError`` into a :class:`UnigaitError`."""
    try:
        return fn()
    except grpc.RpcError as err:
        raise UnigaitError.from_rpc_error(err) from None
