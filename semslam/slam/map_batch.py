"""Map point statistics for many points at once (ORB-SLAM's ComputeDistinctiveDescriptors).

Python objects hold the map; what costs is visiting them one by one and paying numpy's call
overhead per point.  Here the observations' descriptors of all points are gathered once into
one array, and the choice is made by one compiled kernel for binary descriptors (Hamming
distance, the map's usual kind) or per group of points with the same observation count with
the matcher's own distances for any other kind.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numba
import numpy as np
from numpy.typing import NDArray

from semslam.features.matching import HammingMatcher

if TYPE_CHECKING:
    from semslam.core.protocols import Matcher
    from semslam.slam.map import MapPoint

_POPCOUNT = np.array([bin(i).count("1") for i in range(256)], dtype=np.int32)


def compute_distinctive_descriptors(points: list["MapPoint"], matcher: "Matcher") -> None:
    """For each point, the observation descriptor with the least median distance to the
    other observations' descriptors (ORB-SLAM ComputeDistinctiveDescriptors; ties: the
    first observation in insertion order).  Observations by bad keyframes are ignored; a
    point with one observation takes its descriptor, one with none keeps its own.

    The median runs over the full distance row, the zero distance to itself included, as
    ``MapPoint.compute_distinctive_descriptor`` always did.
    """
    owners: list[MapPoint] = []
    counts: list[int] = []
    rows: list[NDArray] = []
    for p in points:
        obs = [kf.keypoints.descriptors[i] for kf, i in p.observations.items() if not kf.bad]
        if obs:
            owners.append(p)
            counts.append(len(obs))
            rows.extend(obs)
    if not owners:
        return
    desc = np.stack(rows)
    cnt = np.asarray(counts, np.intp)
    start = np.zeros(cnt.size, np.intp)
    np.cumsum(cnt[:-1], out=start[1:])
    if isinstance(matcher, HammingMatcher) and desc.dtype == np.uint8:
        chosen = _hamming_choice(desc, start, cnt, _POPCOUNT)
    else:
        chosen = _generic_choice(desc, start, cnt, matcher)
    best = desc[chosen]  # a fresh array: each point's row is its own copy
    for p, d in zip(owners, best):
        p.descriptor = d


def _generic_choice(desc: NDArray, start: NDArray[np.intp], cnt: NDArray[np.intp],
                    matcher: "Matcher") -> NDArray[np.intp]:
    """Row of the chosen descriptor per point, with the matcher's distances (any kind)."""
    chosen = start.copy()  # one observation: the first (and only) row
    for n in np.unique(cnt[cnt >= 2]).tolist():
        sel = np.flatnonzero(cnt == n)
        block = desc[start[sel, None] + np.arange(n)]  # (P_n, n, dim)
        ii, jj = np.triu_indices(n, 1)
        pair = matcher.distances(block[:, ii].reshape(-1, desc.shape[1]),
                                 block[:, jj].reshape(-1, desc.shape[1]))
        pair = np.asarray(pair).reshape(sel.size, ii.size)
        dist = np.zeros((sel.size, n, n), pair.dtype)
        dist[:, ii, jj] = pair
        dist[:, jj, ii] = pair
        chosen[sel] = start[sel] + np.argmin(np.median(dist, axis=2), axis=1)
    return chosen


@numba.njit(cache=True, nogil=True)
def _hamming_choice(desc: NDArray[np.uint8], start: NDArray[np.intp], cnt: NDArray[np.intp],
                    popcount: NDArray[np.int32]) -> NDArray[np.intp]:
    """Row of the chosen descriptor per point: Hamming distances, the median of each row as
    ``np.median`` takes it (the mean of the two middle values for an even count), the first
    least median."""
    out = np.empty(start.size, np.intp)
    dim = desc.shape[1]
    for s in range(start.size):
        n = cnt[s]
        b = start[s]
        if n < 2:
            out[s] = b
            continue
        dist = np.zeros((n, n), np.int32)
        for i in range(n):
            for j in range(i + 1, n):
                d = 0
                for k in range(dim):
                    d += popcount[desc[b + i, k] ^ desc[b + j, k]]
                dist[i, j] = d
                dist[j, i] = d
        best = 0
        best_med = np.inf
        for i in range(n):
            row = np.sort(dist[i])
            h = n // 2
            med = float(row[h]) if n % 2 == 1 else (float(row[h - 1]) + float(row[h])) / 2.0
            if med < best_med:
                best_med = med
                best = i
        out[s] = b + best
    return out
