"""Packing numpy arrays into proto ``Tensor`` messages and back (little-endian, row-major)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from unigait.client.errors import ProtocolError
from unigait.client.proto import pb

_TO_NUMPY: dict[int, np.dtype[Any]] = {
    pb.DTYPE_F32: np.dtype("<f4"),
    pb.DTYPE_U8: np.dtype("u1"),
    pb.DTYPE_U32: np.dtype("<u4"),
}
_FROM_NUMPY: dict[np.dtype[Any], int] = {v: k for k, v in _TO_NUMPY.items()}


def numpy_dtype(dtype: int) -> np.dtype[Any]:
    """The numpy dtype of a proto ``DType`` value."""
    try:
        return _TO_NUMPY[dtype]
    except KeyError:
        raise ProtocolError(f"unsupported tensor dtype {dtype}") from None


def encode(array: np.ndarray, dtype: str = "<f4") -> Any:
    """Pack an array into a proto ``Tensor``.

    Args:
        array: Any array-like; converted to ``dtype`` (``"<f4"``, ``"u1"`` or ``"<u4"``).
        dtype: Target numpy dtype.

    Returns:
        A ``unigait.v1.Tensor`` with the array's shape.
    """
    dt = np.dtype(dtype)
    arr = np.ascontiguousarray(array, dtype=dt)
    # The stubs type enum fields as their wrapper; the value is the enum's int.
    return pb.Tensor(shape=list(arr.shape), dtype=_FROM_NUMPY[dt], data=arr.tobytes())  # type: ignore[arg-type]


def decode(
    tensor: Any, row_shape: Sequence[int] | None = None, dtype: str | None = None
) -> np.ndarray:
    """Unpack a proto ``Tensor`` into a read-only numpy view of its bytes (no copy).

    Args:
        tensor: A ``unigait.v1.Tensor``.
        row_shape: Shape of one row, used when the tensor is absent (an empty batch).
        dtype: numpy dtype to assume when the tensor is absent.

    Returns:
        An array of ``tensor.shape``; ``[0, *row_shape]`` when the message is empty.

    Raises:
        ProtocolError: When the byte count does not match the shape and dtype.
    """
    if not tensor.shape and not tensor.data and tensor.dtype == pb.DTYPE_UNSPECIFIED:
        return np.empty((0, *(row_shape or ())), dtype=np.dtype(dtype or "<f4"))
    dt = numpy_dtype(tensor.dtype)
    shape = tuple(int(s) for s in tensor.shape)
    expected = int(np.prod(shape, dtype=np.int64)) * dt.itemsize
    if len(tensor.data) != expected:
        raise ProtocolError(
            f"tensor of shape {list(shape)} and dtype {dt} needs {expected} bytes, "
            f"got {len(tensor.data)}"
        )
    return np.frombuffer(tensor.data, dtype=dt).reshape(shape)
