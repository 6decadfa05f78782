"""Map point statistics for many points at once (ORB-SLAM's ComputeDistinctiveDescriptors
and UpdateNormalAndDepth).

What costs is visiting points one by one and paying numpy's call overhead per point.  Here
the observations of all points are gathered from the point store's rows at once; the
distinctive descriptor is chosen by one compiled kernel for binary descriptors (Hamming
distance, the map's usual kind) or per group of points with the same observation count with
the matcher's own distances for any other kind.

Computing and writing are separate (:func:`distinctive_descriptors` and
:func:`normals_and_depths` return an update whose ``write`` stores it): local mapping and loop
closing compute without the map lock and write under it, as every write to the point store
must happen (docs/architecture.md).  ``write()`` writes by store rows in one numpy
assignment per field.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from operator import attrgetter
from typing import Any

import numba
import numpy as np
from numpy.typing import NDArray

from semslam.core.protocols import Matcher
from semslam.features.matching import HammingMatcher
from semslam.slam.orb.point_store import MapPoint, Observer, PointStore
from semslam.slam.orb.row_kernels import first_seen_unique

_POPCOUNT = np.array([bin(i).count("1") for i in range(256)], dtype=np.int32)


_ROW = attrgetter("row")
_STORE = attrgetter("store")


def store_rows(points: list[MapPoint]) -> NDArray[np.intp]:
    """The store rows of ``points`` (one C-level pass: no property per point)."""
    return np.fromiter(map(_ROW, points), np.intp, len(points))


def shared_store(points: list[MapPoint]) -> PointStore | None:
    """The one store all ``points`` live in (a map's), or None if they are in several
    (points made outside a map, in tests) or there are none."""
    stores = set(map(_STORE, points))
    return stores.pop() if len(stores) == 1 else None


def one_store(points: list[MapPoint]) -> PointStore:
    """The store all ``points`` live in (the batch statistics need one)."""
    store = shared_store(points)
    if store is None:
        raise ValueError("points of several stores (or none)")
    return store


def _first_seen_keyframes(store: PointStore, ids: NDArray[np.int64]) -> tuple[list[Observer], NDArray[np.intp]]:
    """The keyframes of ``ids`` in first-seen order and each id's position among them."""
    order = first_seen_unique(ids)
    position = np.zeros(int(order.max()) + 1 if order.size else 0, np.intp)
    position[order] = np.arange(order.size)
    by_id = store.keyframes_by_id
    return [by_id[i] for i in order.tolist()], position[ids]


def observation_table(points: list[MapPoint], kf_index: dict[Observer, int] | None = None
                      ) -> tuple[NDArray[np.intp], NDArray[np.intp], NDArray[np.intp], list[Observer]]:
    """Every observation of ``points`` as flat arrays (point row, keyframe row, keypoint
    index), point-major in observation order, and the keyframes the rows refer to.

    With ``kf_index`` only the observations by those keyframes are listed (rows from it);
    without, every observing keyframe gets a row in first-seen order."""
    empty = np.zeros(0, np.intp)
    if not points:
        return empty, empty, empty, [] if kf_index is None else list(kf_index)
    store = one_store(points)
    point_row, ids, kp = store.observation_table(store_rows(points))
    if kf_index is None:
        kfs, kf_row = _first_seen_keyframes(store, ids)
        return point_row, kf_row, kp, kfs
    lookup = np.full(int(ids.max()) + 1 if ids.size else 0, -1, np.intp)
    for kf, k in kf_index.items():
        if kf.id < lookup.size:
            lookup[kf.id] = k
    kf_row = lookup[ids]
    keep = kf_row >= 0
    return point_row[keep], kf_row[keep], kp[keep], list(kf_index)


def _per_keyframe(kf_row: NDArray[np.intp], n_kfs: int) -> list[NDArray[np.intp]]:
    """For each keyframe row k, the positions m with ``kf_row[m] == k`` (ascending)."""
    order = np.argsort(kf_row, kind="stable")
    bounds = np.searchsorted(kf_row[order], np.arange(n_kfs + 1))
    return [order[bounds[k]:bounds[k + 1]] for k in range(n_kfs)]


def gather_keypoints(kfs: list[Observer], kf_row: NDArray[np.intp], kp: NDArray[np.intp]
                     ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.intp]]:
    """(uv, ur, octave) of keypoint ``kp[m]`` of keyframe ``kfs[kf_row[m]]``, one fancy index
    per keyframe."""
    m = kp.size
    uv = np.empty((m, 2))
    ur = np.empty(m)
    octave = np.empty(m, np.intp)
    for kf, sel in zip(kfs, _per_keyframe(kf_row, len(kfs))):
        if sel.size:
            i = kp[sel]
            uv[sel] = kf.xy[i]
            ur[sel] = kf.ur[i]
            octave[sel] = kf.keypoints.octave[i]
    return uv, ur, octave


def gather_descriptors(kfs: list[Observer], kf_row: NDArray[np.intp], kp: NDArray[np.intp]) -> NDArray[Any]:
    """The descriptor of keypoint ``kp[m]`` of keyframe ``kfs[kf_row[m]]`` (row m), one
    fancy index per keyframe (a map's keyframes hold one kind of descriptor)."""
    like = kfs[0].keypoints.descriptors
    out = np.empty((kp.size, like.shape[1]), like.dtype)
    for kf, sel in zip(kfs, _per_keyframe(kf_row, len(kfs))):
        if sel.size:
            out[sel] = kf.keypoints.descriptors[kp[sel]]
    return out


def point_positions(points: list[MapPoint]) -> NDArray[np.float64]:
    """(N, 3) positions of ``points``: one fancy index when they share a store."""
    store = shared_store(points)
    if store is None:
        return np.array([p.pos for p in points]).reshape(-1, 3)
    return store.pos[store_rows(points)]


@dataclass
class DescriptorUpdate:
    """Chosen descriptors (one row per point), to be written under the map lock."""

    points: list[MapPoint] = field(default_factory=list)
    descriptors: NDArray[Any] | None = None

    def write(self) -> None:
        if not self.points or self.descriptors is None:
            return
        one_store(self.points).descriptor[store_rows(self.points)] = self.descriptors


def distinctive_descriptors(points: list[MapPoint], matcher: Matcher) -> DescriptorUpdate:
    """For each point, the observation descriptor with the least median distance to the
    other observations' descriptors (ORB-SLAM ComputeDistinctiveDescriptors; ties: the
    first observation in insertion order).  Observations by bad keyframes are ignored; a
    point with one observation takes its descriptor, one with none keeps its own (it is not
    in the update).

    The median runs over the full distance row, the zero distance to itself included (as
    in ORB-SLAM).
    """
    point_row, kf_row, kp, kfs = observation_table(points)
    good_kf = np.fromiter((not kf.bad for kf in kfs), bool, len(kfs))
    if not good_kf.all():
        keep = good_kf[kf_row]
        point_row, kf_row, kp = point_row[keep], kf_row[keep], kp[keep]
    if not point_row.size:
        return DescriptorUpdate()
    per_point = np.bincount(point_row, minlength=len(points))
    owner_idx = np.flatnonzero(per_point)
    owners = [points[i] for i in owner_idx.tolist()]
    desc = gather_descriptors(kfs, kf_row, kp)  # point-major, in observation order
    cnt = per_point[owner_idx]
    start = np.zeros(cnt.size, np.intp)
    np.cumsum(cnt[:-1], out=start[1:])
    if isinstance(matcher, HammingMatcher) and desc.dtype == np.uint8:
        chosen = _hamming_choice(desc, start, cnt, _POPCOUNT)
    else:
        chosen = _generic_choice(desc, start, cnt, matcher)
    return DescriptorUpdate(owners, desc[chosen])


def compute_distinctive_descriptors(points: list[MapPoint], matcher: Matcher) -> None:
    """:func:`distinctive_descriptors` written at once (the caller holds the map lock)."""
    distinctive_descriptors(points, matcher).write()


@dataclass
class NormalUpdate:
    """Normals of ``points`` and the depth ranges of ``points[ranged]``, to be written
    under the map lock."""

    points: list[MapPoint] = field(default_factory=list)
    normal: NDArray[np.float64] | None = None
    ranged: NDArray[np.intp] = field(default_factory=lambda: np.zeros(0, np.intp))
    min_dist: NDArray[np.float64] = field(default_factory=lambda: np.zeros(0))
    max_dist: NDArray[np.float64] = field(default_factory=lambda: np.zeros(0))

    def write(self) -> None:
        if not self.points or self.normal is None:
            return
        store = one_store(self.points)
        rows = store_rows(self.points)
        store.normal[rows] = self.normal
        store.min_dist[rows[self.ranged]] = self.min_dist
        store.max_dist[rows[self.ranged]] = self.max_dist


def normals_and_depths(points: list[MapPoint], scale_factors: NDArray[np.float64],
                       pos: NDArray[np.float64] | None = None,
                       centers: dict[Observer, NDArray[np.float64]] | None = None,
                       erased: dict[int, set[Observer]] | None = None) -> NormalUpdate:
    """Mean viewing direction of each point and the distance range it can be matched at
    (ORB-SLAM UpdateNormalAndDepth), from the store's observation rows.  Bad points and points without observations are left out; the depth range needs
    the reference keyframe among the observations.

    The map as it will be after a change not made yet (a BA result about to be applied):
    ``pos`` (one row per point) replaces the positions, ``centers`` some keyframes' camera
    centres, and ``erased[point id]`` are observations left out as ``erase_observation``
    will erase them (a point left with <= 1 observation by that goes bad and is left out;
    one that loses its reference keyframe takes the first remaining one, as it will)."""
    if not points:
        return NormalUpdate()
    store = one_store(points)
    rows = store_rows(points)
    owner, ids, kp = store.observation_table(rows)
    per_point = np.bincount(owner, minlength=len(points))
    live = ~store.bad[rows] & (per_point > 0)
    ref_ids = np.fromiter((p.ref_kf.id for p in points), np.int64, len(points))
    # The reference keyframe's keypoint, among all the observations (-1: not observed).
    is_ref = ids == ref_ids[owner]
    ref_kp = np.full(len(points), -1, np.intp)
    ref_kp[owner[is_ref]] = kp[is_ref]
    kept = np.ones(ids.size, bool)
    if erased:
        starts = np.zeros(len(points), np.intp)
        np.cumsum(per_point[:-1], out=starts[1:])
        index = {p.id: j for j, p in enumerate(points)}
        for pid, gone in erased.items():
            j = index.get(pid)
            if j is None or not live[j] or not gone:
                continue
            seg = slice(starts[j], starts[j] + per_point[j])
            gone_ids = {kf.id for kf in gone}
            drop = np.fromiter((i in gone_ids for i in ids[seg].tolist()), bool, int(per_point[j]))
            kept[seg] &= ~drop
            left = ids[seg][~drop]
            if left.size <= 1:
                live[j] = False
            elif int(ref_ids[j]) in gone_ids:
                ref_ids[j] = left[0]
                hit = np.flatnonzero(ids[seg] == left[0])
                ref_kp[j] = kp[seg][hit[0]]
    live_idx = np.flatnonzero(live)
    if not live_idx.size:
        return NormalUpdate()
    used = kept & live[owner]
    kfs, kf_row = _first_seen_keyframes(store, ids[used])
    counts = np.bincount(owner[used], minlength=len(points))[live_idx]
    centers = centers or {}
    center = np.array([centers[kf] if kf in centers else kf.center for kf in kfs])
    xyz = store.pos[rows[live_idx]] if pos is None else np.asarray(pos)[live_idx]
    d = np.repeat(xyz, counts, axis=0) - center[kf_row]
    d /= np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-9)
    starts = np.zeros(live_idx.size, np.intp)
    np.cumsum(counts[:-1], out=starts[1:])
    normals = np.add.reduceat(d, starts, axis=0)
    normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-9)
    rr = np.flatnonzero(ref_kp[live_idx] >= 0)
    if rr.size:
        ref_of = live_idx[rr]
        by_id = store.keyframes_by_id
        levels = np.fromiter((by_id[int(i)].keypoints.octave[k] for i, k in zip(ref_ids[ref_of].tolist(), ref_kp[ref_of].tolist())),
                             np.intp, rr.size)
        ref_center = np.array([centers[kf] if kf in centers else kf.center for kf in map(by_id.__getitem__, ref_ids[ref_of].tolist())])
        dist = np.linalg.norm(xyz[rr] - ref_center, axis=1)
        max_d = dist * scale_factors[levels]
    else:
        max_d = np.zeros(0)
    return NormalUpdate([points[j] for j in live_idx.tolist()], normals, rr, max_d / scale_factors[-1], max_d)


def _generic_choice(desc: NDArray, start: NDArray[np.intp], cnt: NDArray[np.intp],
                    matcher: Matcher) -> NDArray[np.intp]:
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


def warm_up() -> None:
    """Compile (or load from numba's disk cache) the kernel here before local mapping first
    needs it: the first call otherwise compiles inside a critical section (fusion's
    ``replace_point`` runs under the map lock)."""
    desc = np.zeros((3, 32), np.uint8)
    _hamming_choice(desc, np.zeros(1, np.intp), np.full(1, 3, np.intp), _POPCOUNT)
