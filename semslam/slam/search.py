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
    keep = [order[0]]
    for b in order[1:3]:
        if counts[b] >= 0.1 * counts[order[0]] and counts[b] > 0:
            keep.append(b)
    return np.isin(bins, keep)


def project(T_cw: NDArray[np.float64], pts_w: NDArray[np.float64], fx: float, fy: float, cx: float, cy: float
            ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Pixel positions and depths of world points seen from ``T_cw``."""
    pc = pts_w @ T_cw[:3, :3].T + T_cw[:3, 3]
    z = pc[:, 2]
    zs = np.where(np.abs(z) > 1e-9, z, 1e-9)
    uv = np.stack([fx * pc[:, 0] / zs + cx, fy * pc[:, 1] / zs + cy], axis=1)
    return uv, z


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
    qa, qb = [], []
    for node, ia in featvec_a.items():
        ib = featvec_b.get(node)
        if ib is None or len(ib) == 0:
            continue
        ia_arr = np.asarray(ia, np.intp)
        ib_arr = np.asarray(ib, np.intp)
        ia_arr = ia_arr[valid_a[ia_arr]]
        ib_arr = ib_arr[free_b[ib_arr]]
        if len(ia_arr) == 0 or len(ib_arr) == 0:
            continue
        qa.append(np.repeat(ia_arr, len(ib_arr)))
        qb.append(np.tile(ib_arr, len(ia_arr)))
    if not qa:
        return np.zeros(0, np.intp), np.zeros(0, np.intp)
    cq, ct = np.concatenate(qa), np.concatenate(qb)
    qi, ti, _ = matcher.match_candidates(desc_a, desc_b, cq, ct, max_distance, ratio)
    return qi, ti
