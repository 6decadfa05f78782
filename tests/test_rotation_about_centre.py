"""Rotation of a camera with a known centre (``geometry/rotation_about_centre.py``): exact on
analytic cases, robust to wrong matches, and honest when too few agree."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from semslam.geometry.rotation_about_centre import bearings, fit_rotation_about_centre

K = np.array([[525.0, 0.0, 319.5], [0.0, 525.0, 239.5], [0.0, 0.0, 1.0]])


def _scene(rng: np.random.Generator, n: int = 80) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A camera at ``c`` turned by ``R_cw``; ``n`` world points it sees, and their pixels."""
    R_cw = Rotation.from_rotvec(rng.normal(0.0, 0.5, 3)).as_matrix()
    c = rng.normal(0.0, 1.0, 3)
    px = np.column_stack([rng.uniform(20, 620, n), rng.uniform(20, 460, n)])
    depth = rng.uniform(0.8, 6.0, n)
    rays_c = np.column_stack([(px[:, 0] - K[0, 2]) / K[0, 0], (px[:, 1] - K[1, 2]) / K[1, 1], np.ones(n)]) * depth[:, None]
    pts_w = rays_c @ R_cw + c  # X_w = R_cw^T X_c + c
    return R_cw, c, pts_w, px


def _angle_deg(A: np.ndarray, B: np.ndarray) -> float:
    return float(np.degrees(Rotation.from_matrix(A @ B.T).magnitude()))


def test_bearings_are_unit_rays_through_the_pixels() -> None:
    b = bearings(np.array([[319.5, 239.5], [844.5, 239.5]]), K)
    assert np.allclose(b[0], [0, 0, 1]) and np.allclose(b[1], np.array([1, 0, 1]) / np.sqrt(2))


def test_exact_rotation_from_a_start_degrees_off() -> None:
    rng = np.random.default_rng(3)
    R_cw, c, pts, px = _scene(rng)
    R0 = Rotation.from_rotvec(np.radians([0.8, -0.6, 0.3])).as_matrix() @ R_cw  # ~1 deg (8 px) off
    fit = fit_rotation_about_centre(pts, c, px, K, R0)
    assert fit.ok and fit.inliers.all()
    assert _angle_deg(fit.R_cw, R_cw) < 1e-6


def test_wrong_matches_are_trimmed() -> None:
    rng = np.random.default_rng(4)
    R_cw, c, pts, px = _scene(rng, 100)
    px = px + rng.normal(0.0, 0.5, px.shape)  # half-pixel noise
    wrong = rng.choice(100, 30, replace=False)
    px[wrong] = np.column_stack([rng.uniform(0, 640, 30), rng.uniform(0, 480, 30)])
    fit = fit_rotation_about_centre(pts, c, px, K, R_cw)
    assert fit.ok
    assert _angle_deg(fit.R_cw, R_cw) < 0.02
    # Every right match is kept; a wrong one only where it happens to land near its point.
    right = np.setdiff1d(np.arange(100), wrong)
    assert fit.inliers[right].mean() > 0.95 and fit.inliers[wrong].mean() < 0.2


def test_too_few_agreeing_matches_return_the_start() -> None:
    rng = np.random.default_rng(5)
    R_cw, c, pts, px = _scene(rng, 5)
    R0 = Rotation.from_rotvec(np.radians([0.5, 0.0, 0.0])).as_matrix() @ R_cw
    fit = fit_rotation_about_centre(pts, c, px, K, R0)  # 5 < min_inliers = 6
    assert not fit.ok and np.array_equal(fit.R_cw, R0)
    # Points behind the camera never count.
    fit = fit_rotation_about_centre(2 * c - pts[:1].repeat(8, 0), c, px[:1].repeat(8, 0), K, R_cw)
    assert not fit.ok
