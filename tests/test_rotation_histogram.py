"""The rotation-consistency check (ORB-SLAM's ``ComputeThreeMaxima`` over a 30-bin
histogram of the keypoint angle differences, 12-degree bins) against a plain-Python
version of the rule, match by match."""

from __future__ import annotations

import numpy as np

from semslam.slam.orb.search import HISTO_LENGTH, rotation_consistent


def _three_maxima_reference(angle_a: np.ndarray, angle_b: np.ndarray) -> np.ndarray:
    """Bin each match by rot = angle_a - angle_b (mod 360), keep the bins of the three
    largest counts (ties: the lower bin first), the 2nd and 3rd only if >= 10 % of the
    first."""
    bins = []
    for a, b in zip(angle_a.tolist(), angle_b.tolist()):
        rot = (a - b) % 360.0
        bins.append(min(int(rot * HISTO_LENGTH / 360.0), HISTO_LENGTH - 1))
    counts = [bins.count(k) for k in range(HISTO_LENGTH)]
    ranked = sorted(range(HISTO_LENGTH), key=lambda k: (-counts[k], k))
    keep = {ranked[0]} | {k for k in ranked[1:3] if counts[k] > 0 and counts[k] >= 0.1 * counts[ranked[0]]}
    return np.array([b in keep for b in bins], bool)


def test_rotation_consistency_equals_orb_slams_three_maxima() -> None:
    rng = np.random.default_rng(2)
    for n in (1, 5, 40, 600):
        for spread in (2.0, 30.0, 180.0):
            a = rng.uniform(0, 360, n).astype(np.float32)
            b = ((a + rng.normal(0, spread, n)) % 360).astype(np.float32)
            np.testing.assert_array_equal(rotation_consistent(a, b), _three_maxima_reference(a, b))
    assert rotation_consistent(np.zeros(0), np.zeros(0)).shape == (0,)
