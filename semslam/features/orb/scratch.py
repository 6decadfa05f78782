"""Work buffers reused from call to call."""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

__all__ = ["Scratch", "kernel_array"]


def kernel_array(a: NDArray | list, dtype: type) -> NDArray:
    """``a`` as a C-contiguous, writeable array of ``dtype`` (a copy only if needed). Why:
    numba compiles a kernel once per argument type, and a read-only or strided array is
    another type, so such an input would otherwise trigger a compile in the middle of a
    frame."""
    out = np.ascontiguousarray(a, dtype)
    return out if out.flags.writeable else out.copy()


class Scratch:
    """Work buffers reused from call to call (grown as needed). Why: on this machine a
    fresh multi-MB numpy array costs more in page faults than the arithmetic on it."""

    def __init__(self) -> None:
        self._bufs: dict[str, NDArray] = {}

    def get(self, name: str, shape: tuple[int, ...], dtype: type) -> NDArray:
        size = math.prod(shape)
        buf = self._bufs.get(name)
        if buf is None or buf.size < size or buf.dtype != dtype:
            buf = np.empty(max(size, 2 * buf.size if buf is not None else size), dtype)
            self._bufs[name] = buf
        return buf[:size].reshape(shape)
