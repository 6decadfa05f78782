"""The tracking thread's compiled kernels equal their numpy references (multi-view check, local-map rows).

``project_references`` (one numba pass) against ``project_references_reference`` (numpy
array passes) on random keyframes, poses, keypoints and depth images: the same points
tested, in the same order, with the same dynamic flags and measured depths, and positions
equal to rounding.
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from semslam.config import DynamicsConfig
from semslam.dynamics.multiview import project_references, project_references_reference
from semslam.geometry.camera import PinholeCamera

CAM = PinholeCamera(525.0, 525.0, 319.5, 239.5, width=640, height=480)


def _pose(rng: np.random.Generator, rot: float, trans: float) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = cv2.Rodrigues(rng.normal(size=3) * rot)[0]
    T[:3, 3] = rng.normal(size=3) * trans
    return T


@pytest.mark.parametrize("seed", range(12))
def test_compiled_projection_equals_the_numpy_reference(seed: int) -> None:
    rng = np.random.default_rng(seed)
    T_cw = _pose(rng, 0.05, 0.1)
    refs = []
    for k in range(int(rng.integers(0, 6))):
        n = int(rng.integers(0, 1500))
        xy = rng.uniform([-20, -20], [660, 500], (n, 2)).astype(np.float32 if k % 2 else np.float64)
        z = rng.uniform(0.2, 6.0, n).astype(np.float32)
        z[rng.random(n) < 0.1] = 0.0  # keypoints without depth are not projected
        refs.append((T_cw @ _pose(rng, 0.1 if seed % 3 else 0.8, 0.2), xy, z))
    depth = rng.uniform(0.3, 6.0, (480, 640)).astype(np.float32)
    depth[rng.random((480, 640)) < 0.2] = 0.0  # holes: not tested there
    params = DynamicsConfig(depth_threshold_rel=0.02 * (seed % 2))
    got = project_references(T_cw, depth, CAM, refs, params)
    want = project_references_reference(T_cw, depth, CAM, refs, params)
    assert len(got.uv) == len(want.uv)
    assert np.array_equal(got.dynamic, want.dynamic)
    assert np.array_equal(got.z_meas, want.z_meas) and got.z_meas.dtype == want.z_meas.dtype
    np.testing.assert_allclose(got.uv, want.uv, rtol=0, atol=1e-9)
    np.testing.assert_allclose(got.z_proj, want.z_proj, rtol=0, atol=1e-12)
    np.testing.assert_allclose(got.ref_centre, want.ref_centre, rtol=0, atol=1e-12)
    if refs and sum(len(r[2]) for r in refs) > 500:
        assert len(got.uv) > 0  # the draw tests something


def test_no_reference_keyframe_tests_nothing() -> None:
    depth = np.ones((480, 640), np.float32)
    got = project_references(np.eye(4), depth, CAM, [])
    assert len(got.uv) == 0 and got.uv.shape == (0, 2) and got.ref_centre.shape == (0, 3)


@pytest.mark.parametrize("seed", range(8))
def test_compiled_occluder_sampling_equals_the_numpy_reference(seed: int) -> None:
    """The static-occlusion test's segment sampling: seeds with displacements from a pixel
    to far outside the image, occluder maps from sparse to dense, 1/2 and 1/4 resolution."""
    from semslam.dynamics.multiview import occluder_on_segments_reference
    from semslam.dynamics.multiview_kernels import occluder_on_segments

    rng = np.random.default_rng(100 + seed)
    s = 2 if seed % 2 else 4
    occl = rng.random((480 // s, 640 // s)) < [0.002, 0.02, 0.1, 0.4][seed % 4]
    n = int(rng.integers(0, 400))
    uv = rng.uniform([-5, -5], [645, 485], (n, 2))
    delta = rng.normal(size=(n, 2)) * rng.choice([1.0, 10.0, 100.0, 2000.0], (n, 1))
    length = np.maximum(np.linalg.norm(delta, axis=1), 1e-9)
    reach = (length + 2.0) / length
    lin = np.linspace(0.0, 1.0, int(rng.integers(2, 18)))
    got = occluder_on_segments(uv, delta, reach, lin, occl, s)
    want = occluder_on_segments_reference(uv, delta, reach, lin, occl, s)
    assert np.array_equal(got, want)
    if n > 50 and seed % 4:
        assert 0 < got.sum() < n or got.all()  # the draw hits occluders


@pytest.mark.parametrize("seed", range(6))
def test_first_seen_unique_equals_the_numpy_reference(seed: int) -> None:
    """Tracking's local map rows: the distinct rows >= 0 in first-seen order, as the sort-based
    numpy version gives them (empty, all -1, duplicates far apart, large rows)."""
    from semslam.slam.orb.row_kernels import first_seen_unique, first_seen_unique_reference

    rng = np.random.default_rng(seed)
    n = [0, 5, 100, 5000, 40000, 3][seed]
    rows = rng.integers(-1, max(1, n // 2) if seed != 5 else 0, n)
    got = first_seen_unique(rows)
    want = first_seen_unique_reference(rows)
    assert got.dtype == np.intp and np.array_equal(got, want)
