"""Candidate pairs under shared vocabulary nodes (SearchByBoW, local mapping's epipolar
search): the array version lists what the per-node loop it replaced listed, in its order,
which decides ties in the descriptor matching."""

from __future__ import annotations

import numpy as np
import pytest

from semslam.slam.orb.search import node_pairs


def _per_node_loop(fa: dict, fb: dict, keep_a: np.ndarray, keep_b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    qa, qb = [], []
    for node, ia in fa.items():
        ib = fb.get(node)
        if ib is None or len(ib) == 0:
            continue
        a = np.asarray(ia, np.intp)
        b = np.asarray(ib, np.intp)
        a, b = a[keep_a[a]], b[keep_b[b]]
        if len(a) and len(b):
            qa.append(np.repeat(a, len(b)))
            qb.append(np.tile(b, len(a)))
    if not qa:
        return np.zeros(0, np.intp), np.zeros(0, np.intp)
    return np.concatenate(qa), np.concatenate(qb)


def _feature_vector(rng: np.random.Generator, n: int, n_nodes: int) -> dict:
    """Features grouped by node, nodes in a shuffled order (the loop must follow A's order)."""
    node = rng.integers(0, n_nodes, n)
    keys = rng.permutation(np.unique(node)).tolist()
    return {k: rng.permutation(np.flatnonzero(node == k)).tolist() for k in keys}


@pytest.mark.parametrize("seed", range(6))
def test_node_pairs_equal_the_per_node_loop(seed: int) -> None:
    rng = np.random.default_rng(seed)
    n_a, n_b = int(rng.integers(50, 400)), int(rng.integers(50, 400))
    fa, fb = _feature_vector(rng, n_a, 40), _feature_vector(rng, n_b, 40)
    keep_a, keep_b = rng.random(n_a) < 0.7, rng.random(n_b) < 0.6
    want = _per_node_loop(fa, fb, keep_a, keep_b)
    got = node_pairs(fa, fb, keep_a, keep_b)
    assert want[0].size > 0
    np.testing.assert_array_equal(got[0], want[0])
    np.testing.assert_array_equal(got[1], want[1])


def test_node_pairs_without_shared_nodes_or_features() -> None:
    keep = np.ones(10, bool)
    assert node_pairs({}, {1: [0, 1]}, keep, keep)[0].size == 0
    assert node_pairs({1: [0, 1]}, {2: [3]}, keep, keep)[0].size == 0
    assert node_pairs({1: [0, 1]}, {1: [3]}, keep, np.zeros(10, bool))[0].size == 0
    cq, ct = node_pairs({5: np.array([2, 0]), 1: [4]}, {1: [7, 6], 5: [9]}, keep, keep)
    assert cq.tolist() == [2, 0, 4, 4] and ct.tolist() == [9, 9, 7, 6]
