"""Keypoints of a rolling-shutter camera moved to the middle row's time: against points
projected with each row's own pose (an analytic camera turning and moving at constant
velocity), the correction recovers the global-shutter projection at the middle row's time."""

from __future__ import annotations

import numpy as np

from semslam.geometry.camera import PinholeCamera
from semslam.geometry.rolling_shutter import row_time_fraction, to_middle_row, to_middle_row_with_depth_image
from semslam.geometry.se3 import make_pose
from scipy.spatial.transform import Rotation

CAM = PinholeCamera(fx=535.4, fy=539.2, cx=320.1, cy=247.6, width=640, height=480)
READOUT, DT = 0.030, 1 / 30


def _velocity(rate_deg_s: float, speed_m_s: float) -> np.ndarray:
    """Per-frame camera motion V (T_cw(t + dt) = V T_cw(t)): a yaw/pitch turn and a slide."""
    rv = np.deg2rad(rate_deg_s) * DT * np.array([0.3, 1.0, 0.1]) / np.linalg.norm([0.3, 1.0, 0.1])
    return make_pose(Rotation.from_rotvec(rv).as_matrix(), speed_m_s * DT * np.array([1.0, 0.2, -0.3]))


def _frac_pose(V: np.ndarray, s: float) -> np.ndarray:
    """V^s as the module defines it (scaled rotation vector, scaled translation)."""
    rv = Rotation.from_matrix(V[:3, :3]).as_rotvec()
    return make_pose(Rotation.from_rotvec(s * rv).as_matrix(), s * V[:3, 3])


def _rolling_observations(V: np.ndarray, pts_mid: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each point seen at the row where it lands when that row is read (fixed point of
    row -> pose -> row), and its depth then."""
    rows = CAM.project(pts_mid)[:, 1]
    for _ in range(20):
        s = row_time_fraction(rows, 480, READOUT, DT)
        p = np.stack([(_frac_pose(V, si)[:3, :3] @ x + _frac_pose(V, si)[:3, 3]) for si, x in zip(s, pts_mid)])
        rows = CAM.project(p)[:, 1]
    return CAM.project(p), p[:, 2]


def test_rolling_shutter_observations_are_moved_to_the_middle_row() -> None:
    rng = np.random.default_rng(0)
    uv = rng.uniform([20, 20], [620, 460], (300, 2))
    z = rng.uniform(0.8, 4.0, 300)
    pts_mid = CAM.backproject(uv, z)
    V = _velocity(200.0, 0.5)
    obs, z_obs = _rolling_observations(V, pts_mid)
    shear = np.linalg.norm(obs - uv, axis=1)
    assert shear.max() > 25  # the effect is large at 200 deg/s
    frac = row_time_fraction(obs[:, 1], 480, READOUT, DT)
    fixed, z_fixed = to_middle_row(obs, z_obs, frac, V, CAM)
    np.testing.assert_allclose(fixed, uv, atol=1e-6)
    np.testing.assert_allclose(z_fixed, z, atol=1e-9)
    # Without depth only the rotation is undone: the slide's parallax stays (small here).
    ray_only, z0 = to_middle_row(obs, np.zeros(300), frac, V, CAM)
    assert (z0 == 0).all() and np.linalg.norm(ray_only - uv, axis=1).max() < 0.2 * shear.max()


def test_a_global_shutter_or_a_still_camera_changes_nothing() -> None:
    uv = np.array([[10.0, 5.0], [320.0, 240.0], [600.0, 470.0]])
    z = np.array([1.0, 2.0, 0.0])
    for frac, V in ((np.zeros(3), _velocity(200, 0.5)), (row_time_fraction(uv[:, 1], 480, READOUT, DT), np.eye(4))):
        out, zz = to_middle_row(uv, z, frac, V, CAM)
        np.testing.assert_allclose(out, uv, atol=1e-9)
        np.testing.assert_allclose(zz, z, atol=1e-12)


def _scene_depth(uv: np.ndarray) -> np.ndarray:
    """A global depth frame at the middle row's time: a tilted wall 3-4 m away with a box
    1.2 m away in front of its left part (a depth edge at u = 300)."""
    wall = 3.0 + uv[:, 0] / 640 + 0.3 * uv[:, 1] / 480
    return np.where(uv[:, 0] < 300, 1.2, wall)


def test_depth_is_read_where_the_keypoint_lands_not_under_its_raw_pixel() -> None:
    rng = np.random.default_rng(1)
    uv = rng.uniform([40, 20], [600, 460], (400, 2))
    uv = uv[np.abs(uv[:, 0] - 300) > 6]  # not within the slide's parallax of the edge
    z = _scene_depth(uv)
    V = _velocity(200.0, 0.5)
    obs, _ = _rolling_observations(V, CAM.backproject(uv, z))
    frac = row_time_fraction(obs[:, 1], 480, READOUT, DT)
    # Under the raw pixel the depth frame holds another point: across the edge, metres off.
    raw_err = np.abs(_scene_depth(obs) - z)
    assert raw_err.max() > 1.0
    fixed, z_fixed = to_middle_row_with_depth_image(obs, frac, V, CAM, _scene_depth)
    np.testing.assert_allclose(fixed, uv, atol=1e-3)
    np.testing.assert_allclose(z_fixed, z, atol=1e-4)


def test_frame_state_redoes_the_move_from_the_raw_keypoints() -> None:
    from semslam.core.types import Keypoints
    from semslam.slam.orb.frame_builders import RgbdFrameBuilder

    rng = np.random.default_rng(2)
    uv = rng.uniform([40, 20], [600, 460], (50, 2))
    pts_mid = CAM.backproject(uv, rng.uniform(1.0, 3.0, 50))
    V = _velocity(150.0, 0.3)
    obs, z_obs = _rolling_observations(V, pts_mid)
    kps = Keypoints(xy=obs.astype(np.float32), octave=np.zeros(50, np.int32), angle=np.zeros(50, np.float32),
                    response=np.ones(50, np.float32), descriptors=np.zeros((50, 32), np.uint8))
    depth_img = np.zeros((480, 640), np.float32)
    iu, iv = np.rint(obs[:, 0]).astype(int), np.rint(obs[:, 1]).astype(int)
    depth_img[iv, iu] = z_obs
    f = RgbdFrameBuilder(CAM, 40.0).build(0, 0.0, kps, depth_img)
    f.to_middle_row(np.eye(4), DT, READOUT, CAM, 40.0)  # a wrong (zero) velocity first
    f.to_middle_row(V, DT, READOUT, CAM, 40.0)  # then the right one: from the raw keypoints
    np.testing.assert_allclose(f.xy, uv, atol=0.05)  # float32 keypoints, rounded depth pixels
