"""Map point statistics for many points at once (ORB-SLAM's ComputeDistinctiveDescriptors).

Python objects hold the map; what costs is visiting them one by one and paying numpy's call
overhead per point.  Here the observations of all points are gathered once into flat arrays
(descriptor rows fetched with one fancy index per keyframe) and the per-point work is done per
group of points with the same observation count.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from semslam.core.protocols import Matcher
    from semslam.slam.map import KeyFrame, MapPoint


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
    obs_kf: list[KeyFrame] = []
    obs_idx: list[int] = []
    for p in points:
        n = 0
        for kf, i in p.observations.items():
            if not kf.bad:
                obs_kf.append(kf)
                obs_idx.append(i)
                n += 1
        if n:
            owners.append(p)
            counts.append(n)
    if not owners:
        return
    desc = _gather_rows(obs_kf, obs_idx)
    cnt = np.asarray(counts, np.intp)
    start = np.zeros(cnt.size, np.intp)
    np.cumsum(cnt[:-1], out=start[1:])
    chosen = start.copy()  # one observation: the first (and only) row
    for n in np.unique(cnt[cnt >= 2]).tolist():
        rows = np.flatnonzero(cnt == n)
        block = desc[start[rows, None] + np.arange(n)]  # (P_n, n, dim)
        ii, jj = np.triu_indices(n, 1)
        pair = matcher.distances(block[:, ii].reshape(-1, desc.shape[1]),
                                 block[:, jj].reshape(-1, desc.shape[1]))
        pair = np.asarray(pair).reshape(rows.size, ii.size)
        dist = np.zeros((rows.size, n, n), pair.dtype)
        dist[:, ii, jj] = pair
        dist[:, jj, ii] = pair
        chosen[rows] = start[rows] + np.argmin(np.median(dist, axis=2), axis=1)
    best = desc[chosen]  # a fresh array: each point's row is its own copy
    for p, d in zip(owners, best):
        p.descriptor = d


def _gather_rows(obs_kf: list["KeyFrame"], obs_idx: list[int]) -> np.ndarray[Any, Any]:
    """Descriptor rows ``obs_kf[m].keypoints.descriptors[obs_idx[m]]``, one fancy index per
    keyframe."""
    slots: dict[KeyFrame, list[int]] = {}
    for m, kf in enumerate(obs_kf):
        slots.setdefault(kf, []).append(m)
    idx = np.asarray(obs_idx, np.intp)
    first = next(iter(slots)).keypoints.descriptors
    out = np.empty((len(obs_idx), first.shape[1]), first.dtype)
    for kf, ms in slots.items():
        sel = np.asarray(ms, np.intp)
        out[sel] = kf.keypoints.descriptors[idx[sel]]
    return out
