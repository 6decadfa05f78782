"""ORB-SLAM's matchers, vectorised: search by projection (local map, last frame, fusion)
and search by bag-of-words, plus the rotation-consistency filter.

All functions take arrays and return index pairs; they never change the map. Descriptors
are compared by the ``Matcher`` of their kind, with thresholds in its distance (ORB-SLAM's
TH_LOW / TH_HIGH are ``FeatureSpec.th_low`` / ``th_high``).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray
from semslam.core.protocols import Matcher
from semslam.features.keypoint_grid import KeypointGrid

HISTO_LENGTH = 30

IntArray = NDArray[np.intp]


def rotation_consistent(angle_a: NDArray[np.floating], angle_b: NDArray[np.floating]) -> NDArray[np.bool_]:
    """Keep matches whose keypoint rotation falls in the three most common 12-degree bins
    (ORB-SLAM ComputeThreeMaxima: 2nd/3rd bins only if >= 10 % of the first)."""
    if len(angle_a) == 0:
        return np.zeros(0, bool)
    rot = (np.asarray(angle_a) - np.asarray(angle_b)) % 360.0
    bins = np.minimum((rot * HISTO_LENGTH / 360.0).astype(int), HISTO_LENGTH - 1)
    counts = np.bincount(bins, minlength=HISTO_LENGTH)
    order = np.argsort(-counts, kind="stable")
    kept = np.zeros(HISTO_LENGTH, bool)  # a lookup by bin: np.isin sorts (3x the time)
    kept[order[0]] = True
    for b in order[1:3]:
        if counts[b] >= 0.1 * counts[order[0]] and counts[b] > 0:
            kept[b] = True
    return kept[bins]


def search_by_projection(
    uv: NDArray[np.float64],
    radius: NDArray[np.float64],
    level_lo: NDArray[np.intp],
    level_hi: NDArray[np.intp],
    point_desc: NDArray[Any],
    kp_xy: NDArray[np.float64],
    kp_octave: NDArray[np.int32],
    kp_desc: NDArray[Any],
    kp_free: NDArray[np.bool_],
    grid: KeypointGrid | Any | None,
    matcher: Matcher,
    max_distance: float,
    ratio: float = 0.8,
) -> tuple[IntArray, IntArray]:
    """Match projected points (each with its own search radius and pyramid-level window)
    to free keypoints. Returns (point indices, keypoint indices); each keypoint used once.

    ``grid`` is the keypoints' ``KeypointGrid`` (built here when another index or None
    is given)."""
    if len(uv) == 0 or len(kp_xy) == 0:
        return np.zeros(0, np.intp), np.zeros(0, np.intp)
    if not isinstance(grid, KeypointGrid):
        hi = np.asarray(kp_xy).max(axis=0)
        grid = KeypointGrid(kp_xy, kp_octave, int(hi[0]) + 1, int(hi[1]) + 1)
    cq, ct = grid.pairs_in_radius(uv, radius, level_lo, level_hi, kp_free)
    if len(cq) == 0:
        return np.zeros(0, np.intp), np.zeros(0, np.intp)
    qi, ti, _ = matcher.match_candidates(point_desc, kp_desc, cq, ct, max_distance, ratio)
    return qi, ti


def _flat_feature_vector(featvec: dict[int, Any], keep: NDArray[np.bool_]
                         ) -> tuple[NDArray[np.intp], NDArray[np.int64]]:
    """The kept features of a DBoW2 feature vector and their nodes, node by node in the
    vector's order (each node's features contiguous, in its order)."""
    if not featvec:
        return np.zeros(0, np.intp), np.zeros(0, np.int64)
    groups = [np.asarray(ia, np.intp) for ia in featvec.values()]
    idx = np.concatenate(groups)
    node = np.repeat(np.fromiter(featvec.keys(), np.int64, len(featvec)),
                     np.fromiter(map(len, groups), np.intp, len(groups)))
    sel = keep[idx]
    return idx[sel], node[sel]


def node_pairs(featvec_a: dict[int, Any], featvec_b: dict[int, Any], keep_a: NDArray[np.bool_],
               keep_b: NDArray[np.bool_]) -> tuple[IntArray, IntArray]:
    """Every (feature of A, feature of B) pair under one vocabulary node, among the kept
    ones: node by node in A's order, A's features in order, each with B's in order (what
    a loop over A's nodes with ``repeat``/``tile`` gives), in a few array operations
    instead of a few per node."""
    a_idx, a_node = _flat_feature_vector(featvec_a, keep_a)
    b_idx, b_node = _flat_feature_vector(featvec_b, keep_b)
    if a_idx.size == 0 or b_idx.size == 0:
        return np.zeros(0, np.intp), np.zeros(0, np.intp)
    # B's runs of one node (contiguous), looked up by node id.
    run_start = np.flatnonzero(np.r_[True, b_node[1:] != b_node[:-1]])
    run_len = np.diff(np.r_[run_start, b_node.size])
    run_node = b_node[run_start]
    order = np.argsort(run_node, kind="stable")
    pos = np.minimum(np.searchsorted(run_node[order], a_node), order.size - 1)
    hit = run_node[order[pos]] == a_node
    run = order[pos]
    count = np.where(hit, run_len[run], 0)
    total = int(count.sum())
    if total == 0:
        return np.zeros(0, np.intp), np.zeros(0, np.intp)
    first = np.cumsum(count) - count  # where each A feature's pairs begin
    within = np.arange(total) - np.repeat(first, count)
    cq = np.repeat(a_idx, count)
    ct = b_idx[np.repeat(run_start[run], count) + within]
    return cq, ct


def search_by_bow(
    featvec_a: dict[int, list[int]],
    desc_a: NDArray[Any],
    featvec_b: dict[int, list[int]],
    desc_b: NDArray[Any],
    valid_a: NDArray[np.bool_],
    free_b: NDArray[np.bool_],
    matcher: Matcher,
    max_distance: float,
    ratio: float = 0.7,
) -> tuple[IntArray, IntArray]:
    """Match features of A (with map points, ``valid_a``) to features of B that fall under
    the same vocabulary node (ORB-SLAM SearchByBoW). Returns (indices in A, indices in B)."""
    cq, ct = node_pairs(featvec_a, featvec_b, valid_a, free_b)
    if cq.size == 0:
        return cq, ct
    qi, ti, _ = matcher.match_candidates(desc_a, desc_b, cq, ct, max_distance, ratio)
    return qi, ti
