"""Matchers by descriptor kind: HammingMatcher gives exactly what the module-level popcount
code gave before it became a class; L2Matcher agrees with OpenCV's brute force (NORM_L2)
and with a plain reference over candidate pairs, on both its sparse and dense paths."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from semslam.core.protocols import Matcher
from semslam.core.types import DescriptorKind, FeatureSpec, orb_spec
from semslam.features.matching import (
    HammingMatcher,
    L2Matcher,
    match_brute_force,
    match_candidates,
    matcher_for,
)

_POPCOUNT = np.array([bin(i).count("1") for i in range(256)], dtype=np.uint8)


# --------------------------------------------------------------------------- references

def _old_unique_train(qi, ti, dd):  # type: ignore[no-untyped-def]
    if len(qi) == 0:
        return np.zeros(0, np.intp), np.zeros(0, np.intp), np.zeros(0, np.int32)
    order = np.lexsort((dd, ti))
    qi, ti, dd = qi[order], ti[order], dd[order]
    first = np.r_[True, ti[1:] != ti[:-1]]
    return qi[first], ti[first], dd[first]


def _old_match_candidates(desc_query, desc_train, cand_q, cand_t, max_distance, ratio):  # type: ignore[no-untyped-def]
    """The module-level code before the matchers (commit fc1265b), verbatim."""
    if len(cand_q) == 0:
        return np.zeros(0, np.intp), np.zeros(0, np.intp), np.zeros(0, np.int32)
    dist = _POPCOUNT[np.bitwise_xor(desc_query[cand_q], desc_train[cand_t])].sum(axis=1,
                                                                                   dtype=np.int32)
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
    return _old_unique_train(q[sel], t[sel], d[sel])


def _reference_candidates(dist_fn, desc_query, desc_train, cand_q, cand_t, max_distance, ratio):  # type: ignore[no-untyped-def]
    """Plain loops: per query its candidates' distances, best / second, then one query per train."""
    best: dict[int, tuple[float, int]] = {}
    per_q: dict[int, list[tuple[float, int]]] = {}
    for q, t in zip(cand_q.tolist(), cand_t.tolist()):
        per_q.setdefault(q, []).append((dist_fn(desc_query[q], desc_train[t]), t))
    for q, lst in per_q.items():
        lst.sort()
        d0, t0 = lst[0]
        d1 = lst[1][0] if len(lst) > 1 else np.inf
        if d0 <= max_distance and d0 < ratio * d1 and (t0 not in best or d0 < best[t0][0]):
            best[t0] = (d0, q)
    return {(q, t) for t, (_, q) in best.items()}


def _l2(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.linalg.norm(a.astype(np.float64) - b.astype(np.float64)))


def _bf_l2_reference(desc_query: np.ndarray, desc_train: np.ndarray, max_distance: float,
                     ratio: float) -> dict[tuple[int, int], float]:
    """OpenCV's brute force (NORM_L2, k = 2) with the ratio test and one query per train."""
    knn = cv2.BFMatcher(cv2.NORM_L2).knnMatch(desc_query, desc_train, k=2)
    best: dict[int, tuple[float, int]] = {}
    for m, n in knn:
        if m.distance <= max_distance and m.distance < ratio * n.distance:
            if m.trainIdx not in best or m.distance < best[m.trainIdx][0]:
                best[m.trainIdx] = (m.distance, m.queryIdx)
    return {(q, t): d for t, (d, q) in best.items()}


# --------------------------------------------------------------------------- data

def _binary(n: int, seed: int) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 256, (n, 32), dtype=np.uint8)


def _near_copies(base: np.ndarray, rng: np.random.Generator, noise: float) -> np.ndarray:
    """Float descriptors near ``base`` (a shuffled subset plus distractors), like real matches."""
    out = base + rng.normal(0, noise, base.shape).astype(np.float32)
    return np.concatenate([out, rng.random((len(base) // 2, base.shape[1]), dtype=np.float32)])


@pytest.fixture(scope="module")
def sift_pair(shared_data) -> tuple[np.ndarray, np.ndarray]:  # type: ignore[no-untyped-def]
    paths = sorted((shared_data / "kinect_rgbd_5frames" / "color").glob("*.png"))[:2]
    sift = cv2.SIFT_create(500)
    grays = [cv2.imread(str(p), cv2.IMREAD_GRAYSCALE) for p in paths]
    descs = [sift.detectAndCompute(g, None)[1] for g in grays]
    return descs[0], descs[1]


# --------------------------------------------------------------------------- dispatch

def test_matcher_for_dispatches_on_the_descriptor_kind() -> None:
    assert isinstance(matcher_for(orb_spec(1.2, 8)), HammingMatcher)
    sift = FeatureSpec(DescriptorKind.FLOAT, 128, 2 ** (1 / 3), 12, th_low=0.3, th_high=0.5)
    assert isinstance(matcher_for(sift), L2Matcher)
    assert isinstance(HammingMatcher(), Matcher) and isinstance(L2Matcher(), Matcher)


# --------------------------------------------------------------------------- Hamming

@pytest.mark.parametrize("seed", [0, 1, 2])
def test_hamming_candidates_unchanged(seed: int) -> None:
    rng = np.random.default_rng(seed)
    a, b = _binary(300, seed), _binary(400, seed + 10)
    b[:200] = a[:200] ^ (rng.random((200, 32)) < 0.05).astype(np.uint8)  # some near copies
    cq = rng.integers(0, 300, 5000).astype(np.intp)
    ct = rng.integers(0, 400, 5000).astype(np.intp)
    for max_d, ratio in ((50, 0.7), (100, 0.9), (64, 1.0)):
        new = HammingMatcher().match_candidates(a, b, cq, ct, max_d, ratio)
        old = _old_match_candidates(a, b, cq, ct, max_d, ratio)
        for x, y in zip(new, old):
            assert x.dtype == y.dtype and np.array_equal(x, y)
        shortcut = match_candidates(a, b, cq, ct, max_d, ratio)
        assert all(np.array_equal(x, y) for x, y in zip(shortcut, old))
    assert HammingMatcher().distances(a, a).sum() == 0


def test_hamming_brute_force() -> None:
    a, b = _binary(200, 3), _binary(250, 4)
    b[:100] = a[:100]
    qi, ti, dd = HammingMatcher().match_brute_force(a, b, 64, 0.8)
    assert dd.dtype == np.int32 and len(qi) == 100 and np.array_equal(qi, ti)
    assert all(np.array_equal(x, y) for x, y in zip(match_brute_force(a, b, 64, 0.8), (qi, ti, dd)))


# --------------------------------------------------------------------------- L2

@pytest.mark.parametrize("noise", [0.02, 0.1])
def test_l2_brute_force_equals_opencv(noise: float) -> None:
    rng = np.random.default_rng(5)
    a = rng.random((400, 128), dtype=np.float32)
    b = _near_copies(a[rng.permutation(400)[:300]], rng, noise)
    for max_d, ratio in ((np.inf, 0.8), (1.5, 0.9), (0.8, 1.0)):
        qi, ti, dd = L2Matcher().match_brute_force(a, b, max_d, ratio)
        ref = _bf_l2_reference(a, b, max_d, ratio)
        assert set(zip(qi.tolist(), ti.tolist())) == set(ref)
        expected = [ref[(q, t)] for q, t in zip(qi.tolist(), ti.tolist())]
        assert np.allclose(dd, expected, rtol=1e-5, atol=1e-5)
    assert len(L2Matcher().match_brute_force(a, b[:1], np.inf, 0.8)[0]) == 0


def test_l2_brute_force_on_real_sift(sift_pair: tuple[np.ndarray, np.ndarray]) -> None:
    a, b = sift_pair
    qi, ti, dd = L2Matcher().match_brute_force(a, b, np.inf, 0.8)
    ref = _bf_l2_reference(a, b, np.inf, 0.8)
    assert len(ref) > 50
    assert set(zip(qi.tolist(), ti.tolist())) == set(ref)
    assert np.allclose(dd, [ref[(q, t)] for q, t in zip(qi.tolist(), ti.tolist())], rtol=1e-4)


@pytest.mark.parametrize("dense", [False, True])
def test_l2_candidates_equal_reference(dense: bool) -> None:
    rng = np.random.default_rng(7)
    a = rng.random((200, 128), dtype=np.float32)
    b = _near_copies(a[:150], rng, 0.05)
    if dense:  # every query against every train: the BLAS block path
        cq, ct = np.repeat(np.arange(200), len(b)), np.tile(np.arange(len(b)), 200)
    else:  # a few candidates per query: the gathered-rows path
        cq = np.repeat(np.arange(200), 4)
        ct = rng.integers(0, len(b), len(cq))
        ct[::4] = np.minimum(np.arange(200), len(b) - 1)
    for max_d, ratio in ((np.inf, 0.8), (1.0, 0.9), (2.0, 1.0)):
        qi, ti, dd = L2Matcher().match_candidates(a, b, cq.astype(np.intp), ct.astype(np.intp),
                                                  max_d, ratio)
        ref = _reference_candidates(_l2, a, b, cq, ct, max_d, ratio)
        assert set(zip(qi.tolist(), ti.tolist())) == ref
        assert np.allclose(dd, [_l2(a[q], b[t]) for q, t in zip(qi, ti)], rtol=1e-5, atol=1e-5)
    none = np.zeros(0, np.intp)
    assert len(L2Matcher().match_candidates(a, b, none, none, 1.0, 0.8)[0]) == 0


def test_l2_distances() -> None:
    rng = np.random.default_rng(9)
    a, b = rng.random((50, 128), dtype=np.float32), rng.random((60, 128), dtype=np.float32)
    full = L2Matcher().distance_matrix(a, b)
    exact = np.linalg.norm(a[:, None].astype(np.float64) - b[None], axis=2)
    assert np.allclose(full, exact, atol=1e-5)
    assert np.allclose(L2Matcher().distances(a, b[:50]), np.diag(full[:, :50]), atol=1e-5)
