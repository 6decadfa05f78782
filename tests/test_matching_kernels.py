"""The compiled matching kernels equal their numpy references on random inputs; the point
store and the keyframes' point rows stay in sync with the objects."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from semslam.core.types import Keypoints, orb_spec
from semslam.features.keypoint_grid import KeypointGrid
from semslam.features.matching_kernels import hamming_rows, select_best
from semslam.slam.orb.map import KeyFrame, Map

_POPCOUNT = np.array([bin(i).count("1") for i in range(256)], dtype=np.uint8)


def _select_reference(cand_q, cand_t, dist, max_distance, ratio):
    """The numpy selection the kernel replaced (two lexsorts)."""
    integer = np.issubdtype(dist.dtype, np.integer)
    order = np.lexsort((dist, cand_q))
    q, t, d = cand_q[order], cand_t[order], dist[order]
    first = np.r_[True, q[1:] != q[:-1]]
    idx_first = np.nonzero(first)[0]
    has_second = np.r_[idx_first[1:], len(q)] - idx_first > 1
    second = np.full(len(idx_first), np.iinfo(np.int32).max if integer else np.inf,
                     np.int64 if integer else np.float64)
    second[has_second] = d[idx_first[has_second] + 1]
    best = d[idx_first].astype(np.int64 if integer else np.float64)
    ok = (best <= max_distance) & (best < ratio * second)
    sel = idx_first[ok]
    qi, ti, dd = q[sel], t[sel], d[sel]
    order = np.lexsort((dd, ti))
    qi, ti, dd = qi[order], ti[order], dd[order]
    first = np.r_[True, ti[1:] != ti[:-1]] if len(ti) else np.zeros(0, bool)
    return qi[first], ti[first], dd[first]


@pytest.mark.parametrize("seed", range(5))
def test_hamming_rows_equal_popcount_table(seed: int) -> None:
    rng = np.random.default_rng(seed)
    a = rng.integers(0, 256, (300, 32), dtype=np.uint8)
    b = rng.integers(0, 256, (200, 32), dtype=np.uint8)
    ia, ib = rng.integers(0, 300, 1000), rng.integers(0, 200, 1000)
    ref = _POPCOUNT[a[ia] ^ b[ib]].sum(axis=1)
    assert np.array_equal(hamming_rows(a, b, ia, ib), ref)
    assert hamming_rows(a[:, :31], b[:, :31], ia, ib) is None  # not whole 64-bit words


@pytest.mark.parametrize("seed", range(10))
@pytest.mark.parametrize("kind", ["int", "float"])
def test_select_best_equals_numpy_reference(seed: int, kind: str) -> None:
    rng = np.random.default_rng(seed)
    n = 400
    cq, ct = rng.integers(0, 60, n), rng.integers(0, 80, n)
    # Few distinct distances: many ties, for best, second best and train ownership.
    dist = rng.integers(0, 12, n).astype(np.int32 if kind == "int" else np.float64)
    for ratio in (0.8, 1.0):
        got = select_best(cq, ct, dist, 9, ratio)
        ref = _select_reference(cq, ct, dist, 9, ratio)
        for g, r in zip(got, ref):
            assert np.array_equal(g, r)


@pytest.mark.parametrize("seed", range(5))
def test_grid_pairs_equal_kdtree_ball_query(seed: int) -> None:
    rng = np.random.default_rng(seed)
    xy = rng.uniform([-5, -5], [645, 485], (1500, 2))  # some keypoints outside the image
    octave = rng.integers(0, 8, 1500).astype(np.int32)
    free = rng.random(1500) > 0.2
    uv = rng.uniform([-20, -20], [660, 500], (700, 2))
    radius = rng.uniform(2, 60, 700)
    lo = rng.integers(-1, 6, 700)
    hi = lo + rng.integers(0, 3, 700)
    cq, ct = KeypointGrid(xy, octave, 640, 480).pairs_in_radius(uv, radius, lo, hi, free)
    got = set(zip(cq.tolist(), ct.tolist()))
    lists = cKDTree(xy).query_ball_point(uv, r=radius)
    ref = {(q, t) for q, ts in enumerate(lists) for t in ts
           if free[t] and lo[q] <= octave[t] <= hi[q]}
    assert got == ref
    assert len(got) == len(cq)  # no pair twice
    # In ORB-SLAM's GetFeaturesInArea order: by query, then by grid cell (row-major), then
    # by keypoint index within a cell (the matcher keeps the first of equal distances).
    col = np.clip(np.floor(xy[:, 0] / 10.0), 0, 63).astype(int)
    row = np.clip(np.floor(xy[:, 1] / 10.0), 0, 47).astype(int)
    cell = row * 64 + col
    assert sorted(zip(cq.tolist(), ct.tolist()), key=lambda p: (p[0], cell[p[1]], p[1])) == list(
        zip(cq.tolist(), ct.tolist()))


def _keyframe(slam_map: Map, n: int, ur: np.ndarray) -> KeyFrame:
    kps = Keypoints(np.zeros((n, 2), np.float32), np.zeros(n, np.int32), np.zeros(n, np.float32),
                    np.zeros(n, np.float32), np.zeros((n, 32), np.uint8))
    kf = KeyFrame(slam_map.new_kf_id(), 0, 0.0, np.eye(4), kps, np.zeros((n, 2)), np.zeros(n, np.float32), ur,
                  [None] * n)
    slam_map.add_keyframe(kf)
    return kf


def test_point_store_and_rows_follow_the_objects() -> None:
    rng = np.random.default_rng(0)
    m = Map(orb_spec(1.2, 8))
    kfs = [_keyframe(m, 50, np.where(rng.random(50) > 0.5, 1.0, -1.0)) for _ in range(4)]
    pts = []
    for _ in range(6000):  # past the initial capacity: the arrays grow
        p = m.new_point(rng.normal(size=3), rng.integers(0, 256, 32, dtype=np.uint8), kfs[0])
        pts.append(p)
    for k, kf in enumerate(kfs):
        for i in range(50):
            p = pts[(7 * i + k) % 200]
            if kf not in p.observations:
                p.add_observation(kf, i)
                kf.points[i] = p
    m.set_bad_point(pts[7])
    m.replace_point(pts[14], pts[21])
    kfs[1].points[3] = None
    store = m.store
    for kf in kfs:
        rows = np.array([-1 if p is None else p.row for p in kf.points])
        assert np.array_equal(kf.points.rows, rows)
        assert kf.tracked_points(2) == sum(1 for p in kf.points if p is not None and not p.bad
                                           and sum(2 if o.ur[i] >= 0 else 1 for o, i in p.observations.items()) >= 2)
    for p in pts[:200]:
        assert store.n_kf_obs[p.row] == len(p.observations)
        assert p.n_obs == sum(2 if o.ur[i] >= 0 else 1 for o, i in p.observations.items())
    assert pts[7].bad and store.bad[pts[7].row] and pts[14].bad
    p = pts[5999]
    p.pos = np.array([1.0, 2.0, 3.0])
    assert np.array_equal(store.pos[p.row], [1.0, 2.0, 3.0])
    with pytest.raises(AttributeError):  # fixed length: no list methods
        kfs[0].points.append(None)
