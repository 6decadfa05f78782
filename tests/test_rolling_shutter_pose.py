"""The joint rolling-shutter fit recovers a known middle-row pose and velocity from raw
rolling-shutter projections (each point seen at its own row's time), starting from the
velocity a motion model would give when a turn starts (none)."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from semslam.backend.rolling_shutter_pose import solve_rolling_shutter_pose
from semslam.geometry.camera import PinholeCamera
from semslam.geometry.rolling_shutter import row_time_fraction
from semslam.geometry.se3 import invert, make_pose

CAM = PinholeCamera(fx=535.4, fy=539.2, cx=320.1, cy=247.6, width=640, height=480)
K = (CAM.fx, CAM.fy, CAM.cx, CAM.cy)
READOUT, DT = 0.030, 1 / 30


def _motion(rate_deg_s: float, speed_m_s: float) -> np.ndarray:
    rv = np.deg2rad(rate_deg_s) * DT * np.array([0.2, 1.0, 0.1]) / np.linalg.norm([0.2, 1.0, 0.1])
    return make_pose(Rotation.from_rotvec(rv).as_matrix(), speed_m_s * DT * np.array([1.0, 0.2, -0.3]))


def _frac(V: np.ndarray, s: float) -> np.ndarray:
    return make_pose(Rotation.from_rotvec(s * Rotation.from_matrix(V[:3, :3]).as_rotvec()).as_matrix(), s * V[:3, 3])


def _observe(T_cw: np.ndarray, V: np.ndarray, pts_w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Raw pixels (each at the row where it is read) and the rows' time fractions."""
    pc = pts_w @ T_cw[:3, :3].T + T_cw[:3, 3]
    rows = CAM.project(pc)[:, 1]
    for _ in range(20):
        s = row_time_fraction(rows, 480, READOUT, DT)
        p = np.stack([_frac(V, si)[:3, :3] @ x + _frac(V, si)[:3, 3] for si, x in zip(s, pc)])
        uv = CAM.project(p)
        rows = uv[:, 1]
    return uv, row_time_fraction(rows, 480, READOUT, DT)


def _scene(T_cw: np.ndarray, n: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    uv = rng.uniform([30, 30], [610, 450], (n, 2))
    pc = CAM.backproject(uv, rng.uniform(1.0, 4.0, n))
    T_wc = invert(T_cw)
    return pc @ T_wc[:3, :3].T + T_wc[:3, 3]


def _angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.degrees(np.linalg.norm(Rotation.from_matrix(a[:3, :3] @ b[:3, :3].T).as_rotvec())))


def test_pose_and_velocity_are_recovered_from_a_turn_that_the_motion_model_missed() -> None:
    T_true = make_pose(Rotation.from_rotvec([0.1, -0.3, 0.05]).as_matrix(), [0.2, -0.1, 0.4])
    V_true = _motion(200.0, 0.4)
    pts = _scene(T_true, 300, 0)
    uv, frac = _observe(T_true, V_true, pts)
    rng = np.random.default_rng(1)
    uv_noisy = uv + rng.normal(0, 0.5, uv.shape)
    # Start: the pose off by ~1 deg / 2 cm, no velocity (the camera was still a frame ago).
    T0 = make_pose(Rotation.from_rotvec([0.01, 0.012, -0.005]).as_matrix(), [0.02, -0.01, 0.01]) @ T_true
    res = solve_rolling_shutter_pose(T0, np.eye(4), pts, uv_noisy, frac, np.ones(len(pts)), K,
                                     prior_sigma_rad=1.0, prior_sigma_m=1.0)
    assert _angle_deg(res.T_cw, T_true) < 0.05  # 0.5 px noise
    assert np.linalg.norm(res.T_cw[:3, 3] - T_true[:3, 3]) < 1e-3
    rate = np.degrees(np.linalg.norm(Rotation.from_matrix(res.velocity_cw[:3, :3]).as_rotvec())) / DT
    assert abs(rate - 200.0) < 5.0
    assert _angle_deg(res.velocity_cw, V_true) < 0.1
    assert res.inliers.mean() > 0.95


def test_outliers_are_flagged_and_do_not_move_the_fit() -> None:
    T_true = make_pose(np.eye(3), [0.0, 0.0, 0.5])
    V_true = _motion(120.0, 0.2)
    pts = _scene(T_true, 200, 2)
    uv, frac = _observe(T_true, V_true, pts)
    bad = np.arange(0, 200, 10)
    uv[bad] += 40.0
    res = solve_rolling_shutter_pose(T_true, V_true, pts, uv, frac, np.ones(200), K)
    assert not res.inliers[bad].any() and res.inliers.sum() >= 175
    assert _angle_deg(res.T_cw, T_true) < 0.01


def test_a_still_camera_stays_still() -> None:
    T_true = np.eye(4)
    pts = _scene(T_true, 100, 3)
    uv, frac = _observe(T_true, np.eye(4), pts)
    res = solve_rolling_shutter_pose(T_true, np.eye(4), pts, uv, frac, np.ones(100), K)
    np.testing.assert_allclose(res.velocity_cw, np.eye(4), atol=1e-6)
    np.testing.assert_allclose(res.T_cw, T_true, atol=1e-6)
