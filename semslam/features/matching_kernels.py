"""Compiled kernels behind the matchers (numba, ``nogil`` so tracking and local mapping
can match at the same time, ``cache=True`` so the JIT runs once per machine).

- ``hamming_rows``: Hamming distance of paired rows, by 64-bit popcount;
- ``select_best``: per query the best candidate (ties: the first one), the ratio test
  against the second best, then each train point kept for its closest query only: the
  rules of ``semslam.features.matching`` in one pass instead of two lexsorts.

``semslam.features.matching_reference`` keeps the numpy versions the tests compare with.
"""

from __future__ import annotations

from typing import Any

import numba
import numpy as np
from numpy.typing import NDArray

_M1 = np.uint64(0x5555555555555555)
_M2 = np.uint64(0x3333333333333333)
_M4 = np.uint64(0x0F0F0F0F0F0F0F0F)
_H01 = np.uint64(0x0101010101010101)


@numba.njit(cache=True, nogil=True, inline="always")
def _popcount64(x: np.uint64) -> int:
    x = x - ((x >> np.uint64(1)) & _M1)
    x = (x & _M2) + ((x >> np.uint64(2)) & _M2)
    x = (x + (x >> np.uint64(4))) & _M4
    return int((x * _H01) >> np.uint64(56))


@numba.njit(cache=True, nogil=True)
def _hamming_rows_u64(a: NDArray[np.uint64], b: NDArray[np.uint64], ia: NDArray[np.intp],
                      ib: NDArray[np.intp]) -> NDArray[np.int32]:
    out = np.empty(len(ia), np.int32)
    words = a.shape[1]
    for k in range(len(ia)):
        ra, rb = ia[k], ib[k]
        s = 0
        for w in range(words):
            s += _popcount64(a[ra, w] ^ b[rb, w])
        out[k] = s
    return out


def as_words(desc: NDArray[np.uint8]) -> NDArray[np.uint64] | None:
    """Binary descriptors as 64-bit words (a view when possible), None when the row length
    is not a multiple of 8 bytes."""
    if desc.ndim != 2 or desc.shape[1] % 8:
        return None
    return np.ascontiguousarray(desc).view(np.uint64)


def hamming_rows(a: NDArray[np.uint8], b: NDArray[np.uint8], ia: NDArray[np.intp] | None = None,
                 ib: NDArray[np.intp] | None = None) -> NDArray[np.int32] | None:
    """Hamming distance between ``a[ia[k]]`` and ``b[ib[k]]`` (row k of each when no
    indices are given); None when the rows are not whole 64-bit words."""
    wa, wb = as_words(a), as_words(b)
    if wa is None or wb is None:
        return None
    if ia is None or ib is None:
        ia = ib = np.arange(len(a), dtype=np.intp)
    return _hamming_rows_u64(wa, wb, np.asarray(ia, np.intp), np.asarray(ib, np.intp))


@numba.njit(cache=True, nogil=True)
def _select_best(cand_q: NDArray[np.intp], cand_t: NDArray[np.intp], dist: NDArray[Any], n_query: int,
                 n_train: int, max_distance: float, ratio: float
                 ) -> tuple[NDArray[np.intp], NDArray[np.intp], NDArray[Any]]:
    best = np.full(n_query, np.inf)
    second = np.full(n_query, np.inf)
    arg = np.full(n_query, -1, np.intp)
    for k in range(len(cand_q)):
        q = cand_q[k]
        d = float(dist[k])
        if d < best[q]:
            second[q] = best[q]
            best[q] = d
            arg[q] = k
        elif d < second[q]:
            second[q] = d
    # Each train point keeps its closest query (ties: the lowest query index).
    owner = np.full(n_train, -1, np.intp)
    for q in range(n_query):
        k = arg[q]
        if k < 0 or not (best[q] <= max_distance and best[q] < ratio * second[q]):
            continue
        t = cand_t[k]
        if owner[t] < 0 or best[q] < best[cand_q[owner[t]]]:
            owner[t] = k
    n = 0
    for t in range(n_train):
        if owner[t] >= 0:
            n += 1
    qi = np.empty(n, np.intp)
    ti = np.empty(n, np.intp)
    dd = np.empty(n, dist.dtype)
    n = 0
    for t in range(n_train):  # sorted by train index, as the numpy version returns them
        k = owner[t]
        if k >= 0:
            qi[n], ti[n], dd[n] = cand_q[k], t, dist[k]
            n += 1
    return qi, ti, dd


def select_best(cand_q: NDArray[np.intp], cand_t: NDArray[np.intp], dist: NDArray[Any], max_distance: float,
                ratio: float) -> tuple[NDArray[np.intp], NDArray[np.intp], NDArray[Any]]:
    """Best train point per query among its candidate pairs, the ratio test, each train
    point used once; results sorted by train index."""
    cand_q = np.asarray(cand_q, np.intp)
    cand_t = np.asarray(cand_t, np.intp)
    if len(cand_q) == 0:
        return np.zeros(0, np.intp), np.zeros(0, np.intp), np.zeros(0, dist.dtype)
    return _select_best(cand_q, cand_t, dist, int(cand_q.max()) + 1, int(cand_t.max()) + 1,
                        float(max_distance), float(ratio))


def warm_up() -> None:
    """Compile the kernels for the types the matchers use (see ``semslam.features.jit``)."""
    d = np.zeros((2, 32), np.uint8)
    idx = np.array([0, 1], np.intp)
    hamming_rows(d, d, idx, idx)
    select_best(idx, idx, np.array([1, 2], np.int32), 50, 0.8)
    select_best(idx, idx, np.array([1.0, 2.0]), 0.5, 0.8)
