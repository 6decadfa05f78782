"""Binary descriptor matching: brute force with a ratio test, or over candidate pairs
(e.g. keypoints near a motion-model projection, as ORB-SLAM's search by projection)."""

from __future__ import annotations

import cv2
import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

_POPCOUNT = np.array([bin(i).count("1") for i in range(256)], dtype=np.uint8)

Matches = tuple[NDArray[np.intp], NDArray[np.intp], NDArray[np.int32]]


def _empty() -> Matches:
    return np.zeros(0, np.intp), np.zeros(0, np.intp), np.zeros(0, np.int32)


def hamming_pairs(a: NDArray[np.uint8], b: NDArray[np.uint8]) -> NDArray[np.int32]:
    """Hamming distance between row ``k`` of ``a`` and row ``k`` of ``b``."""
    return _POPCOUNT[np.bitwise_xor(a, b)].sum(axis=1, dtype=np.int32)


def match_brute_force(desc_query: NDArray[np.uint8], desc_train: NDArray[np.uint8], max_distance: int, ratio: float) -> Matches:
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


def _unique_train(qi: NDArray[np.intp], ti: NDArray[np.intp], dd: NDArray[np.int32]) -> Matches:
    """Keep, for every train index, only its closest query."""
    if len(qi) == 0:
        return _empty()
    order = np.lexsort((dd, ti))
    qi, ti, dd = qi[order], ti[order], dd[order]
    first = np.r_[True, ti[1:] != ti[:-1]]
    return qi[first], ti[first], dd[first]


def match_candidates(
    desc_query: NDArray[np.uint8],
    desc_train: NDArray[np.uint8],
    cand_q: NDArray[np.intp],
    cand_t: NDArray[np.intp],
    max_distance: int,
    ratio: float,
) -> Matches:
    """Best train point per query among its candidate pairs, with the ratio test against
    the second-best candidate and each train point used at most once."""
    if len(cand_q) == 0:
        return _empty()
    dist = hamming_pairs(desc_query[cand_q], desc_train[cand_t])
    order = np.lexsort((dist, cand_q))
    q, t, d = cand_q[order], cand_t[order], dist[order]
    first = np.r_[True, q[1:] != q[:-1]]
    idx_first = np.nonzero(first)[0]
    has_second = np.r_[idx_first[1:], len(q)] - idx_first > 1
    second = np.full(len(idx_first), np.iinfo(np.int32).max, np.int64)
    second[has_second] = d[idx_first[has_second] + 1]
    best = d[idx_first].astype(np.int64)
    ok = (best <= max_distance) & (best < ratio * second)
    sel = idx_first[ok]
    return _unique_train(q[sel], t[sel], d[sel])


def pairs_within_radius(xy_query: NDArray[np.floating], xy_train: NDArray[np.floating], radius: float) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    """All (query, train) index pairs closer than ``radius`` pixels."""
    if len(xy_query) == 0 or len(xy_train) == 0:
        return np.zeros(0, np.intp), np.zeros(0, np.intp)
    tree = cKDTree(np.asarray(xy_train, np.float64))
    lists = tree.query_ball_point(np.asarray(xy_query, np.float64), r=radius)
    counts = np.fromiter((len(x) for x in lists), np.intp, len(lists))
    cand_q = np.repeat(np.arange(len(lists)), counts)
    cand_t = np.fromiter((j for x in lists for j in x), np.intp, int(counts.sum()))
    return cand_q, cand_t
