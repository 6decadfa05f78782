"""The compiled quadtree (``orb.quadtree_kernels``) against the vectorised numpy one it
replaced (``distribute_quadtree_leaves_numpy``): the same kept points and the same
partition into leaves (leaf numbers may differ), for both split rules, on random point
sets (several levels, shuffled levels, duplicates, float positions, budgets <= 0) and on
the FAST candidates of real frames. The literal list-based ports of ORB-SLAM's
``DistributeOctTree`` and Algorithm 3 are checked in test_orb_slam_extractor.py and
test_qtree_orb.py, which now run the compiled version."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from semslam.features.orb import (
    SplitRule,
    build_pyramid,
    detect_levels,
    detection_levels,
    distribute_quadtree_leaves,
    features_per_level,
    region_sizes,
)
from semslam.features.orb.quadtree import distribute_quadtree_leaves_numpy


def _same_selection(args: tuple, rule: SplitRule) -> bool:
    keep, leaf = distribute_quadtree_leaves(*args, rule=rule)
    keep_ref, leaf_ref = distribute_quadtree_leaves_numpy(*args, rule=rule)
    if not np.array_equal(keep, keep_ref) or not np.array_equal(leaf < 0, leaf_ref < 0):
        return False
    # Same partition: the (new, reference) leaf pairs are a bijection.
    pairs = np.unique(np.c_[leaf, leaf_ref], axis=0)
    return len(pairs) == len(np.unique(leaf)) == len(np.unique(leaf_ref))


def _random_case(rng: np.random.Generator, n_levels: int, clustered: bool, messy: bool) -> tuple:
    xs, ys, levels, widths, heights, wanted = [], [], [], [], [], []
    for level in range(n_levels):
        w, h = int(rng.integers(2, 420)), int(rng.integers(2, 320))
        n = int(rng.integers(0, 900))
        if clustered:
            cx, cy, c = rng.integers(0, w, 4), rng.integers(0, h, 4), rng.integers(0, 4, n)
            x = np.clip((cx[c] + rng.normal(0, w / 12, n)).astype(int), 0, w - 1)
            y = np.clip((cy[c] + rng.normal(0, h / 12, n)).astype(int), 0, h - 1)
            flat = np.unique(y * w + x)
        else:
            flat = rng.choice(w * h, size=min(n, w * h), replace=False)
        x, y = (flat % w).astype(np.float64), (flat // w).astype(np.float64)
        if messy and len(x) > 4:  # duplicated pixels and sub-pixel positions
            x = np.concatenate([x, x[:4]]) + 0.9 * rng.random(len(x) + 4)
            y = np.concatenate([y, y[:4]])
        xs.append(x), ys.append(y), levels.append(np.full(len(x), level))
        widths.append(w), heights.append(h), wanted.append(int(rng.integers(-1, 320)))
    x, y, level = np.concatenate(xs), np.concatenate(ys), np.concatenate(levels)
    order = rng.permutation(len(x)) if messy else np.arange(len(x))
    response = rng.integers(0, 25, len(x)).astype(np.float32)  # many ties
    high = rng.random(len(x)) < rng.random()
    return (x[order], y[order], response, level[order], np.array(widths), np.array(heights), np.array(wanted),
            high)


@pytest.mark.parametrize("rule", [SplitRule.ORB_SLAM, SplitRule.HIGH_QUALITY])
def test_equals_numpy_version_on_random_points(rule: SplitRule) -> None:
    rng = np.random.default_rng(0 if rule is SplitRule.ORB_SLAM else 1)
    for case in range(400):
        args = _random_case(rng, int(rng.integers(1, 5)), clustered=case % 2 == 1, messy=case % 3 == 0)
        assert _same_selection(args, rule), case


@settings(max_examples=80, deadline=None)
@given(st.integers(2, 90), st.integers(2, 70), st.integers(-1, 50), st.integers(0, 2**31 - 1),
       st.sampled_from([SplitRule.ORB_SLAM, SplitRule.HIGH_QUALITY]))
def test_equals_numpy_version_property(width: int, height: int, n_wanted: int, seed: int, rule: SplitRule) -> None:
    rng = np.random.default_rng(seed)
    n = int(rng.integers(0, min(300, width * height)))
    flat = rng.choice(width * height, size=n, replace=False)
    args = (flat % width, flat // width, rng.integers(0, 6, n).astype(np.float64), np.zeros(n, np.int64),
            np.array([width]), np.array([height]), np.array([n_wanted]), rng.random(n) < 0.5)
    assert _same_selection(args, rule)


def test_equals_numpy_version_on_real_candidates(shared_data: Path) -> None:
    paths = sorted((shared_data / "kinect_rgbd_5frames" / "color").glob("*.png"))
    paths += sorted((shared_data / "images_people").glob("*.png"))
    if not paths:
        pytest.skip("no real frames")
    for path in paths:
        gray = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
        images = detection_levels(build_pyramid(gray, 8, 1.2).levels)
        x, y, score, level = detect_levels(images, 20, 7)
        widths, heights = region_sizes(images)
        for n_features in (500, 1000, 3000):
            wanted = features_per_level(n_features, 8, 1.2)
            for rule in (SplitRule.ORB_SLAM, SplitRule.HIGH_QUALITY):
                assert _same_selection((x, y, score, level, widths, heights, wanted, score >= 20), rule), path


def test_bad_levels_are_refused() -> None:
    one = np.array([1.0])
    with pytest.raises(ValueError, match="level"):
        distribute_quadtree_leaves(one, one, one, np.array([1]), np.array([10]), np.array([10]), np.array([5]))
    with pytest.raises(ValueError, match="high"):
        distribute_quadtree_leaves(one, one, one, np.array([0]), np.array([10]), np.array([10]), np.array([5]),
                                   rule=SplitRule.HIGH_QUALITY)
