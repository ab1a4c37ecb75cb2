"""Access to the generated protobuf and gRPC modules (built from ../proto by the package build)."""

from __future__ import annotations

try:
    from unigait._proto.v1 import unigait_pb2 as pb
    from unigait._proto.v1 import unigait_pb2_grpc as pb_grpc
except ImportError as exc:  # pragma: no cover - only on a broken install
    raise ImportError(
        "unigait: the gRPC stubs are missing; they are generated from proto/ when the package "
        "is built. Reinstall with `pip install ./client-py` (or `pip install -e ./client-py`)."
    ) from exc

__all__ = ["pb", "pb_grpc"]
