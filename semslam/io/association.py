"""Timestamp association between two streams (trajectories, rgb and depth images).

Two algorithms, because the two reference tools differ:

``associate`` (evo's ``sync.associate_trajectories``, nearest time): walk over the stream
with *fewer* stamps and give each stamp its nearest stamp in the other stream if it lies
within ``max_diff`` (inclusive). A stamp of the longer stream can be used by several
stamps of the shorter one, and on an exact tie the earlier stamp wins. This is what
ATE/RPE use, so the numbers agree with ``evo_ape`` / ``evo_rpe``.

``match_timestamps`` (TUM ``associate.py``): take all candidate pairs closer than
``max_diff`` (strictly), then accept them greedily from the smallest difference up, using
every stamp at most once. This is the right choice for rgb <-> depth, where reusing one
depth image for two colour images would be wrong.

On well-separated streams (both sampled at similar rates) the two give the same pairs;
they differ when one stream is much denser or stamps are nearly equidistant.
Both are pure functions of arrays of seconds.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

IntArray = NDArray[np.intp]


def _nearest_sorted(
    queries: NDArray[np.float64], stamps: NDArray[np.float64], max_diff: float
) -> tuple[IntArray, IntArray]:
    """Indices (into ``queries``, into sorted ``stamps``) of nearest matches within max_diff.

    Upper neighbour wins only if strictly closer, so ties go to the earlier stamp.
    """
    inside = (queries >= stamps[0] - max_diff) & (queries <= stamps[-1] + max_diff)
    q_idx = np.flatnonzero(inside)
    q = queries[q_idx]
    upper = np.searchsorted(stamps, q, side="right")
    upper = np.minimum(upper, len(stamps) - 1)
    diff_up = stamps[upper] - q
    lower = np.maximum(upper - 1, 0)
    diff_low = np.where(upper > 0, q - stamps[lower], np.inf)
    take_up = (diff_up <= max_diff) & (diff_up < diff_low)
    take_low = ~take_up & (diff_low <= max_diff) & (diff_low <= diff_up)
    keep = take_up | take_low
    best = np.where(take_up, upper, lower)
    return q_idx[keep].astype(np.intp), best[keep].astype(np.intp)


def _nearest_unsorted(
    queries: NDArray[np.float64], stamps: NDArray[np.float64], max_diff: float
) -> tuple[IntArray, IntArray]:
    """Brute-force nearest match (first minimum) for stamps that are not sorted."""
    q_out, s_out = [], []
    for i, q in enumerate(queries):
        diffs = np.abs(stamps - q)
        j = int(np.argmin(diffs))
        if diffs[j] <= max_diff:
            q_out.append(i)
            s_out.append(j)
    return np.asarray(q_out, dtype=np.intp), np.asarray(s_out, dtype=np.intp)


def associate(
    t_ref: ArrayLike, t_est: ArrayLike, max_diff: float = 0.02, offset: float = 0.0
) -> tuple[IntArray, IntArray]:
    """Associate two trajectories' stamps as evo's ``associate_trajectories`` does.

    ``offset`` is added to ``t_est`` before matching (estimate clock = reference clock -
    offset). Returns index arrays ``(idx_ref, idx_est)`` of equal length, ordered by the
    stream with fewer stamps (the estimate when both have the same count). Indices of the
    longer stream may repeat. Empty arrays when nothing matches.
    """
    ref = np.asarray(t_ref, dtype=np.float64).reshape(-1)
    est = np.asarray(t_est, dtype=np.float64).reshape(-1)
    if len(ref) == 0 or len(est) == 0:
        empty = np.zeros(0, dtype=np.intp)
        return empty, empty.copy()
    est_longer = len(est) > len(ref)
    if est_longer:
        short, long_, long_offset = ref, est, offset
    else:
        short, long_, long_offset = est, ref, -offset
    long_shifted = long_ + long_offset
    if np.all(np.diff(long_shifted) >= 0):
        i_short, i_long = _nearest_sorted(short, long_shifted, max_diff)
    else:
        i_short, i_long = _nearest_unsorted(short, long_shifted, max_diff)
    if est_longer:
        return i_short, i_long
    return i_long, i_short


def match_timestamps(
    t_first: ArrayLike, t_second: ArrayLike, max_diff: float = 0.02, offset: float = 0.0
) -> tuple[IntArray, IntArray]:
    """One-to-one association with TUM ``associate.py`` semantics.

    Candidate pairs have ``|t_first - (t_second + offset)| < max_diff``; they are accepted
    greedily by increasing difference (ties by first stamp, then second stamp, as Python's
    tuple sort in associate.py), each stamp used once. Returns ``(idx_first, idx_second)``
    sorted by ``t_first``.
    """
    a = np.asarray(t_first, dtype=np.float64).reshape(-1)
    b = np.asarray(t_second, dtype=np.float64).reshape(-1) + offset
    empty = np.zeros(0, dtype=np.intp)
    if len(a) == 0 or len(b) == 0:
        return empty, empty.copy()
    order_b = np.argsort(b, kind="stable")
    b_sorted = b[order_b]
    # All candidate pairs: for each a, the b's in (a - max_diff, a + max_diff).
    # The window is widened a little so rounding cannot drop a pair; the exact test below
    # decides.
    slack = max_diff + 1e-9 * np.maximum(1.0, np.abs(a))
    lo = np.searchsorted(b_sorted, a - slack, side="left")
    hi = np.searchsorted(b_sorted, a + slack, side="right")
    counts = hi - lo
    if counts.sum() == 0:
        return empty, empty.copy()
    ia = np.repeat(np.arange(len(a)), counts)
    starts = np.repeat(lo - np.cumsum(counts) + counts, counts)
    ib = order_b[starts + np.arange(counts.sum())]
    diff = np.abs(a[ia] - b[ib])
    ok = diff < max_diff
    ia, ib, diff = ia[ok], ib[ok], diff[ok]
    order = np.lexsort((b[ib], a[ia], diff))
    used_a = np.zeros(len(a), dtype=bool)
    used_b = np.zeros(len(b), dtype=bool)
    out_a, out_b = [], []
    for k in order:
        i, j = ia[k], ib[k]
        if not used_a[i] and not used_b[j]:
            used_a[i] = used_b[j] = True
            out_a.append(i)
            out_b.append(j)
    ra = np.asarray(out_a, dtype=np.intp)
    rb = np.asarray(out_b, dtype=np.intp)
    order_out = np.lexsort((rb, a[ra])) if len(ra) else np.zeros(0, dtype=np.intp)
    return ra[order_out], rb[order_out]
