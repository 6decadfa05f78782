"""Map point statistics for many points at once (ORB-SLAM's ComputeDistinctiveDescriptors
and UpdateNormalAndDepth).

Python objects hold the map; what costs is visiting them one by one and paying numpy's call
overhead per point.  Here the observations of all points are gathered once into arrays; the
distinctive descriptor is chosen by one compiled kernel for binary descriptors (Hamming
distance, the map's usual kind) or per group of points with the same observation count with
the matcher's own distances for any other kind.

Computing and writing are separate (:func:`distinctive_descriptors` and
:func:`normals_and_depths` return an update whose ``write`` stores it): local mapping and loop
closing compute without the map lock and write under it, as every write to the point store
must happen (docs/architecture.md).  ``write(store)`` writes by store rows in one numpy
assignment per field; without a store, attribute by attribute.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from itertools import chain, repeat
from operator import attrgetter
from typing import TYPE_CHECKING, Any

import numba
import numpy as np
from numpy.typing import NDArray

from semslam.features.matching import HammingMatcher

if TYPE_CHECKING:
    from semslam.core.protocols import Matcher
    from semslam.slam.map import KeyFrame, MapPoint, PointStore

_POPCOUNT = np.array([bin(i).count("1") for i in range(256)], dtype=np.int32)


_ROW = attrgetter("_row")
_STORE = attrgetter("_store")


def store_rows(points: list["MapPoint"]) -> NDArray[np.intp]:
    """The store rows of ``points`` (one C-level pass: no property per point)."""
    return np.fromiter(map(_ROW, points), np.intp, len(points))


def shared_store(points: list["MapPoint"]) -> "PointStore | None":
    """The one store all ``points`` live in (a map's), or None if they are in several
    (points made outside a map, in tests) or there are none."""
    stores = set(map(_STORE, points))
    return stores.pop() if len(stores) == 1 else None


def observation_table(points: list["MapPoint"], kf_index: dict["KeyFrame", int] | None = None
                      ) -> tuple[NDArray[np.intp], NDArray[np.intp], NDArray[np.intp], list["KeyFrame"]]:
    """Every observation of ``points`` as flat arrays (point row, keyframe row, keypoint
    index), point-major in observation order, and the keyframes the rows refer to.

    With ``kf_index`` only the observations by those keyframes are listed (rows from it);
    without, every observing keyframe gets a row in first-seen order."""
    # Flattened with chain/map (loops in C): tens of thousands of observations per call.
    obs_dicts = [p.observations for p in points]
    counts = np.fromiter(map(len, obs_dicts), np.intp, len(obs_dicts))
    obs_kf = list(chain.from_iterable(obs_dicts))
    kp = np.fromiter(chain.from_iterable(d.values() for d in obs_dicts), np.intp, len(obs_kf))
    point_row = np.repeat(np.arange(len(obs_dicts), dtype=np.intp), counts)
    if kf_index is None:
        kfs = list(dict.fromkeys(obs_kf))  # first-seen order
        kf_index = {kf: k for k, kf in enumerate(kfs)}
        kf_row = np.fromiter(map(kf_index.__getitem__, obs_kf), np.intp, len(obs_kf))
        return point_row, kf_row, kp, kfs
    kf_row = np.fromiter(map(kf_index.get, obs_kf, repeat(-1, len(obs_kf))), np.intp, len(obs_kf))
    keep = kf_row >= 0
    return point_row[keep], kf_row[keep], kp[keep], list(kf_index)


def _per_keyframe(kf_row: NDArray[np.intp], n_kfs: int) -> list[NDArray[np.intp]]:
    """For each keyframe row k, the positions m with ``kf_row[m] == k`` (ascending)."""
    order = np.argsort(kf_row, kind="stable")
    bounds = np.searchsorted(kf_row[order], np.arange(n_kfs + 1))
    return [order[bounds[k]:bounds[k + 1]] for k in range(n_kfs)]


def gather_keypoints(kfs: list["KeyFrame"], kf_row: NDArray[np.intp], kp: NDArray[np.intp]
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


def gather_descriptors(kfs: list["KeyFrame"], kf_row: NDArray[np.intp], kp: NDArray[np.intp]) -> NDArray[Any]:
    """The descriptor of keypoint ``kp[m]`` of keyframe ``kfs[kf_row[m]]`` (row m), one
    fancy index per keyframe (a map's keyframes hold one kind of descriptor)."""
    like = kfs[0].keypoints.descriptors
    out = np.empty((kp.size, like.shape[1]), like.dtype)
    for kf, sel in zip(kfs, _per_keyframe(kf_row, len(kfs))):
        if sel.size:
            out[sel] = kf.keypoints.descriptors[kp[sel]]
    return out


def point_positions(points: list["MapPoint"]) -> NDArray[np.float64]:
    """(N, 3) positions of ``points``: one fancy index when they share a store."""
    store = shared_store(points)
    if store is None:
        return np.array([p.pos for p in points]).reshape(-1, 3)
    return store.pos[store_rows(points)]


@dataclass
class DescriptorUpdate:
    """Chosen descriptors (one row per point), to be written under the map lock."""

    points: list["MapPoint"] = field(default_factory=list)
    descriptors: NDArray[Any] | None = None

    def write(self, store: "PointStore | None" = None) -> None:
        if not self.points or self.descriptors is None:
            return
        if store is not None:
            store.descriptor[store_rows(self.points)] = self.descriptors
            return
        for p, d in zip(self.points, self.descriptors):
            p.descriptor = d


def distinctive_descriptors(points: list["MapPoint"], matcher: "Matcher") -> DescriptorUpdate:
    """For each point, the observation descriptor with the least median distance to the
    other observations' descriptors (ORB-SLAM ComputeDistinctiveDescriptors; ties: the
    first observation in insertion order).  Observations by bad keyframes are ignored; a
    point with one observation takes its descriptor, one with none keeps its own (it is not
    in the update).

    The median runs over the full distance row, the zero distance to itself included, as
    ``MapPoint.compute_distinctive_descriptor`` always did.
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


def compute_distinctive_descriptors(points: list["MapPoint"], matcher: "Matcher") -> None:
    """:func:`distinctive_descriptors` written at once (the caller holds the map lock)."""
    distinctive_descriptors(points, matcher).write()


@dataclass
class NormalUpdate:
    """Normals of ``points`` and the depth ranges of ``points[ranged]``, to be written
    under the map lock."""

    points: list["MapPoint"] = field(default_factory=list)
    normal: NDArray[np.float64] | None = None
    ranged: NDArray[np.intp] = field(default_factory=lambda: np.zeros(0, np.intp))
    min_dist: NDArray[np.float64] = field(default_factory=lambda: np.zeros(0))
    max_dist: NDArray[np.float64] = field(default_factory=lambda: np.zeros(0))

    def write(self, store: "PointStore | None" = None) -> None:
        if not self.points or self.normal is None:
            return
        if store is not None:
            rows = store_rows(self.points)
            store.normal[rows] = self.normal
            store.min_dist[rows[self.ranged]] = self.min_dist
            store.max_dist[rows[self.ranged]] = self.max_dist
            return
        for p, n in zip(self.points, self.normal):
            p.normal = n
        for j, mn, mx in zip(self.ranged.tolist(), self.min_dist.tolist(), self.max_dist.tolist()):
            p = self.points[j]
            p.max_dist = mx
            p.min_dist = mn


def normals_and_depths(points: list["MapPoint"], scale_factors: NDArray[np.float64],
                       pos: NDArray[np.float64] | None = None,
                       centers: dict["KeyFrame", NDArray[np.float64]] | None = None,
                       erased: dict[int, set["KeyFrame"]] | None = None) -> NormalUpdate:
    """Mean viewing direction of each point and the distance range it can be matched at
    (ORB-SLAM UpdateNormalAndDepth): one pass over the observations in Python, the rest in
    numpy.  Bad points and points without observations are left out; the depth range needs
    the reference keyframe among the observations.

    The map as it will be after a change not made yet (a BA result about to be applied):
    ``pos`` (one row per point) replaces the positions, ``centers`` some keyframes' camera
    centres, and ``erased[point id]`` are observations left out as ``erase_observation``
    will erase them (a point left with <= 1 observation by that goes bad and is left out;
    one that loses its reference keyframe takes the first remaining one, as it will)."""
    erased = erased or {}
    centers = centers or {}
    live: list[MapPoint] = []
    live_idx: list[int] = []
    obs_kfs: list[list[KeyFrame]] = []
    refs: list[tuple[KeyFrame, int] | None] = []
    for j, p in enumerate(points):
        if p.bad or not p.observations:
            continue
        gone = erased.get(p.id)
        if gone:
            kfs = [kf for kf in p.observations if kf not in gone]
            if len(kfs) <= 1:
                continue
            ref = p.ref_kf if p.ref_kf not in gone else kfs[0]
        else:
            kfs = list(p.observations)
            ref = p.ref_kf
        live.append(p)
        live_idx.append(j)
        obs_kfs.append(kfs)
        idx = p.observations.get(ref)
        refs.append(None if idx is None else (ref, idx))
    if not live:
        return NormalUpdate()
    flat = list(chain.from_iterable(obs_kfs))  # loops in C: thousands of observations
    kf_row = {kf: k for k, kf in enumerate(dict.fromkeys(flat))}  # first-seen order
    rows = np.fromiter(map(kf_row.__getitem__, flat), np.intp, len(flat))
    counts = np.fromiter(map(len, obs_kfs), np.intp, len(live))
    center = np.array([centers[kf] if kf in centers else kf.center for kf in kf_row])
    xyz = point_positions(live) if pos is None else np.asarray(pos)[live_idx]
    d = np.repeat(xyz, counts, axis=0) - center[rows]
    d /= np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-9)
    starts = np.zeros(len(live), np.intp)
    np.cumsum(counts[:-1], out=starts[1:])
    normals = np.add.reduceat(d, starts, axis=0)
    normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-9)
    ref_rows: list[int] = []
    ref_kfs: list[int] = []
    ref_levels: list[int] = []
    for j, r in enumerate(refs):
        if r is not None:
            ref_rows.append(j)
            ref_kfs.append(kf_row[r[0]])
            ref_levels.append(int(r[0].keypoints.octave[r[1]]))
    rr = np.asarray(ref_rows, np.intp)
    if rr.size:
        dist = np.linalg.norm(xyz[rr] - center[ref_kfs], axis=1)
        max_d = dist * scale_factors[np.asarray(ref_levels, np.intp)]
    else:
        max_d = np.zeros(0)
    return NormalUpdate(live, normals, rr, max_d / scale_factors[-1], max_d)


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


def warm_up() -> None:
    """Compile (or load from numba's disk cache) the kernel here before local mapping first
    needs it: the first call otherwise compiles inside a critical section (fusion's
    ``replace_point`` runs under the map lock)."""
    desc = np.zeros((3, 32), np.uint8)
    _hamming_choice(desc, np.zeros(1, np.intp), np.full(1, 3, np.intp), _POPCOUNT)
