"""Descriptor matching, one ``Matcher`` per descriptor kind: ``HammingMatcher`` for binary
descriptors (ORB), ``L2Matcher`` for float ones (SIFT); ``matcher_for(spec)`` picks it.

Both match by brute force with a ratio test, or over candidate pairs (e.g. keypoints
near a projection, as ORB-SLAM's search by projection), with the same rules: the best
train point of each query passes if it is within ``max_distance`` and closer than
``ratio`` times the second best, and each train point keeps only its closest query.
"""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from semslam.core import registry
from semslam.core.protocols import Matcher
from semslam.core.types import FeatureSpec
from semslam.features.matching_kernels import hamming_rows, select_best

_POPCOUNT = np.array([bin(i).count("1") for i in range(256)], dtype=np.uint8)

#: (query indices, train indices, distances): int32 Hamming distances, float64 L2 ones.
Matches = tuple[NDArray[np.intp], NDArray[np.intp], NDArray[Any]]


def matcher_for(spec: FeatureSpec) -> Matcher:
    """The matcher for the spec's descriptor kind (registry kinds ``binary`` / ``float``)."""
    return registry.create("matcher", spec.kind.value)


def _empty(dtype: type = np.int32) -> Matches:
    return np.zeros(0, np.intp), np.zeros(0, np.intp), np.zeros(0, dtype)


def _unique_train(qi: NDArray[np.intp], ti: NDArray[np.intp], dd: NDArray[Any]) -> Matches:
    """Keep, for every train index, only its closest query."""
    if len(qi) == 0:
        return _empty(dd.dtype.type)
    order = np.lexsort((dd, ti))
    qi, ti, dd = qi[order], ti[order], dd[order]
    first = np.r_[True, ti[1:] != ti[:-1]]
    return qi[first], ti[first], dd[first]


def _select_candidates(cand_q: NDArray[np.intp], cand_t: NDArray[np.intp], dist: NDArray[Any],
                       max_distance: float, ratio: float) -> Matches:
    """Best train point per query among its candidate pairs (ties: the first candidate),
    the ratio test against the second-best candidate, each train point used at most once
    (ties: the lowest query); sorted by train index. One compiled pass
    (``matching_kernels.select_best``)."""
    return select_best(cand_q, cand_t, dist, max_distance, ratio)


class HammingMatcher:
    """Binary descriptors (uint8 rows), Hamming distance by a byte popcount table; exact
    int32 distances."""

    def distances(self, a: NDArray[np.uint8], b: NDArray[np.uint8]) -> NDArray[np.int32]:
        """Hamming distance between row ``k`` of ``a`` and row ``k`` of ``b``."""
        d = hamming_rows(a, b) if len(a) else None
        return d if d is not None else _POPCOUNT[np.bitwise_xor(a, b)].sum(axis=1, dtype=np.int32)

    def match_candidates(self, desc_query: NDArray[np.uint8], desc_train: NDArray[np.uint8],
                         cand_q: NDArray[np.intp], cand_t: NDArray[np.intp], max_distance: float,
                         ratio: float) -> Matches:
        """Best train point per query among its candidate pairs (see the module doc)."""
        if len(cand_q) == 0:
            return _empty()
        dist = hamming_rows(desc_query, desc_train, cand_q, cand_t)
        if dist is None:
            dist = self.distances(desc_query[cand_q], desc_train[cand_t])
        return _select_candidates(cand_q, cand_t, dist, max_distance, ratio)

    def match_brute_force(self, desc_query: NDArray[np.uint8], desc_train: NDArray[np.uint8],
                          max_distance: float, ratio: float) -> Matches:
        """Nearest neighbour per query passing the ratio test; each train point used once."""
        if len(desc_query) == 0 or len(desc_train) < 2:
            return _empty()
        knn = cv2.BFMatcher(cv2.NORM_HAMMING).knnMatch(desc_query, desc_train, k=2)
        qi, ti, dd = [], [], []
        for pair in knn:
            if len(pair) < 2:
                continue
            m, n = pair
            if m.distance <= max_distance and m.distance < ratio * n.distance:
                qi.append(m.queryIdx)
                ti.append(m.trainIdx)
                dd.append(m.distance)
        return _unique_train(np.array(qi, np.intp), np.array(ti, np.intp), np.array(dd, np.int32))


class L2Matcher:
    """Float descriptors (float32 rows), Euclidean distance.

    Dense blocks (brute force, or candidate pairs that cover at least 1/8 of the block of
    their queries x trains, as search by bag-of-words over a flat vocabulary does) use
    ``|q|^2 + |t|^2 - 2 q.t`` with one matrix product (BLAS, in float64: in float32 the
    cancellation costs ~1e-4 relative on close pairs); sparse candidate pairs use the
    difference of the gathered rows (float32 einsum, in chunks)."""

    _CHUNK = 65536  # candidate pairs per gather (two 32 MB blocks of 128-d rows)
    _ROWS = 2048  # query rows per dense block
    _MIN_DENSITY = 1 / 8

    def distances(self, a: NDArray[np.floating], b: NDArray[np.floating]) -> NDArray[np.float64]:
        """L2 distance between row ``k`` of ``a`` and row ``k`` of ``b``."""
        d = np.asarray(a, np.float32) - np.asarray(b, np.float32)
        return np.sqrt(np.einsum("ij,ij->i", d, d).astype(np.float64))

    def distance_matrix(self, a: NDArray[np.floating], b: NDArray[np.floating]
                        ) -> NDArray[np.float64]:
        """All L2 distances (len(a) x len(b)) by one matrix product."""
        a = np.asarray(a, np.float64)
        b = np.asarray(b, np.float64)
        d2 = np.einsum("ij,ij->i", a, a)[:, None] + np.einsum("ij,ij->i", b, b)[None, :]
        d2 -= 2.0 * (a @ b.T)
        return np.sqrt(np.maximum(d2, 0.0))

    def match_candidates(self, desc_query: NDArray[np.floating], desc_train: NDArray[np.floating],
                         cand_q: NDArray[np.intp], cand_t: NDArray[np.intp], max_distance: float,
                         ratio: float) -> Matches:
        """Best train point per query among its candidate pairs (see the module doc)."""
        if len(cand_q) == 0:
            return _empty(np.float64)
        uq, iq = np.unique(cand_q, return_inverse=True)
        ut, it = np.unique(cand_t, return_inverse=True)
        if len(cand_q) >= self._MIN_DENSITY * len(uq) * len(ut):
            # Non-candidates are infinitely far; the dense selection is the sparse one.
            block = np.full((len(uq), len(ut)), np.inf)
            block[iq, it] = self.distance_matrix(desc_query[uq], desc_train[ut])[iq, it]
            qi, ti, dd = _select_dense(block, max_distance, ratio)
            return _unique_train(uq[qi], ut[ti], dd)
        dist = np.empty(len(cand_q), np.float64)
        for i in range(0, len(cand_q), self._CHUNK):
            j = min(i + self._CHUNK, len(cand_q))
            dist[i:j] = self.distances(desc_query[cand_q[i:j]], desc_train[cand_t[i:j]])
        return _select_candidates(cand_q, cand_t, dist, max_distance, ratio)

    def match_brute_force(self, desc_query: NDArray[np.floating], desc_train: NDArray[np.floating],
                          max_distance: float, ratio: float) -> Matches:
        """Nearest neighbour per query passing the ratio test; each train point used once."""
        if len(desc_query) == 0 or len(desc_train) < 2:
            return _empty(np.float64)
        parts = []
        for i in range(0, len(desc_query), self._ROWS):
            block = self.distance_matrix(desc_query[i:i + self._ROWS], desc_train)
            qi, ti, dd = _select_dense(block, max_distance, ratio)
            parts.append((qi + i, ti, dd))
        qi, ti, dd = (np.concatenate([p[k] for p in parts]) for k in range(3))
        return _unique_train(qi, ti, dd)


def _select_dense(dist: NDArray[np.float64], max_distance: float, ratio: float) -> Matches:
    """Per row of a distance block: the nearest column if within ``max_distance`` and
    closer than ``ratio`` times the second nearest (inf when there is none)."""
    rows = np.arange(len(dist))
    if dist.shape[1] < 2:
        best_t = np.zeros(len(dist), np.intp)
        second = np.full(len(dist), np.inf)
    else:
        two = np.argpartition(dist, 1, axis=1)[:, :2]
        d2 = dist[rows[:, None], two]
        swap = d2[:, 1] < d2[:, 0]
        best_t = np.where(swap, two[:, 1], two[:, 0])
        second = np.where(swap, d2[:, 0], d2[:, 1])
    best = dist[rows, best_t]
    ok = np.isfinite(best) & (best <= max_distance) & (best < ratio * second)
    return rows[ok].astype(np.intp), best_t[ok].astype(np.intp), best[ok]


# ---------------------------------------------------------------------------- binary shortcuts
# Module-level functions for callers that only ever see ORB descriptors (frame_to_keyframe).
_HAMMING = HammingMatcher()


def hamming_pairs(a: NDArray[np.uint8], b: NDArray[np.uint8]) -> NDArray[np.int32]:
    """Hamming distance between row ``k`` of ``a`` and row ``k`` of ``b``."""
    return _HAMMING.distances(a, b)


def match_brute_force(desc_query: NDArray[np.uint8], desc_train: NDArray[np.uint8],
                      max_distance: int, ratio: float) -> Matches:
    """``HammingMatcher().match_brute_force``."""
    return _HAMMING.match_brute_force(desc_query, desc_train, max_distance, ratio)


def match_candidates(desc_query: NDArray[np.uint8], desc_train: NDArray[np.uint8],
                     cand_q: NDArray[np.intp], cand_t: NDArray[np.intp], max_distance: int,
                     ratio: float) -> Matches:
    """``HammingMatcher().match_candidates``."""
    return _HAMMING.match_candidates(desc_query, desc_train, cand_q, cand_t, max_distance, ratio)


def pairs_within_radius(xy_query: NDArray[np.floating], xy_train: NDArray[np.floating],
                        radius: float) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    """All (query, train) index pairs closer than ``radius`` pixels."""
    if len(xy_query) == 0 or len(xy_train) == 0:
        return np.zeros(0, np.intp), np.zeros(0, np.intp)
    tree = cKDTree(np.asarray(xy_train, np.float64))
    lists = tree.query_ball_point(np.asarray(xy_query, np.float64), r=radius)
    counts = np.fromiter((len(x) for x in lists), np.intp, len(lists))
    cand_q = np.repeat(np.arange(len(lists)), counts)
    cand_t = np.fromiter((j for x in lists for j in x), np.intp, int(counts.sum()))
    return cand_q, cand_t
