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


def test_gyro_rate_is_read_at_the_frame_time_not_where_the_window_mean_lags() -> None:
    from semslam.core.imu import ImuSamples

    # A turn speeding up at 4000 deg/s^2, read at 200 Hz with ADIS16448-like noise.
    t = np.arange(0.0, 0.2, 0.005)
    axis = np.array([0.3, 1.0, 0.1]) / np.linalg.norm([0.3, 1.0, 0.1])
    truth = np.deg2rad(50.0 + 4000.0 * t)[:, None] * axis
    noisy = truth + np.random.default_rng(3).normal(0.0, 2.4e-3, truth.shape)
    samples = ImuSamples(t, noisy, np.zeros_like(noisy))
    at = 0.151  # between readings: the line through the last 30 ms is read there
    rate = samples.gyro_rate_at(at, 0.03)
    want = np.deg2rad(50.0 + 4000.0 * at) * axis
    lag = np.linalg.norm(noisy[(t > at - 0.03) & (t <= at)].mean(axis=0) - want)
    assert np.linalg.norm(rate - want) < 0.01 < lag  # the window's mean: 15 ms behind, ~1 rad/s off
    assert samples.gyro_rate_at(-1.0, 0.03) is None  # no reading before the time
    np.testing.assert_allclose(samples.gyro_rate_at(0.0, 0.03), noisy[0])  # one reading: itself
    np.testing.assert_allclose(samples.gyro_rate_at(0.005, 0.03), noisy[:2].mean(axis=0))


def test_the_imu_gives_the_camera_motion_in_the_camera_frame() -> None:
    """Rate: the gyro's less its bias, turned into the camera. Velocity (once initialised): the
    derivative of the camera centre ``p_b(t) + R_wb(t) t_bc`` of a body sliding at ``v`` and
    turning at ``w_b``, by finite differences, in the camera frame."""
    from semslam.config.schema import ImuConfig
    from semslam.core.imu import ADIS16448, ImuCalibration, ImuSamples
    from semslam.core.types import Frame
    from semslam.geometry.se3 import invert, so3_exp
    from semslam.slam.orb.motion_priors.inertial import InertialPrior

    R_bc = Rotation.from_euler("xyz", [90, 0, 90], degrees=True).as_matrix()  # EuRoC-like mounting
    T_bc = make_pose(R_bc, [-0.02, -0.06, 0.01])
    w_b, bias, v_w = np.array([-3.5, 0.9, 0.1]), np.array([0.01, -0.02, 0.005]), np.array([0.3, -0.1, 0.05])
    t = np.arange(0.0, 0.1, 0.005)
    gyro = np.tile(w_b + bias, (t.size, 1))
    frame = Frame(3, 0.1, np.zeros((4, 4, 3), np.uint8), imu=ImuSamples(t, gyro, np.zeros_like(gyro)))
    prior = InertialPrior(ImuConfig(), ImuCalibration(ADIS16448, T_bc))
    prior.gyro_bias = bias
    R_wb0 = Rotation.from_euler("zyx", [30, -10, 5], degrees=True).as_matrix()
    T_cw = invert(make_pose(R_wb0, [1.0, 2.0, 0.5]) @ T_bc)
    before = prior.camera_motion(frame, T_cw)  # not initialised: no velocity yet
    assert before is not None and before.velocity is None
    np.testing.assert_allclose(before.rate, R_bc.T @ w_b, atol=1e-9)
    prior.gravity, prior.velocity = np.array([0.0, 0.0, -9.81]), v_w
    motion = prior.camera_motion(frame, T_cw)
    assert motion is not None and motion.velocity is not None

    def centre(h: float) -> np.ndarray:
        return np.array([1.0, 2.0, 0.5]) + v_w * h + R_wb0 @ so3_exp(w_b * h) @ T_bc[:3, 3]

    h = 1e-6
    want_w = (centre(h) - centre(-h)) / (2 * h)
    np.testing.assert_allclose(motion.velocity, T_cw[:3, :3] @ want_w, atol=1e-6)
    assert prior.camera_motion(frame, None).velocity is None  # the last frame not tracked
    assert prior.camera_motion(Frame(3, 0.1, frame.rgb), T_cw) is None  # no readings
    assert InertialPrior(ImuConfig(rolling_shutter=False), ImuCalibration(ADIS16448)).camera_motion(frame, T_cw) is None


def test_camera_motion_over_an_interval_is_the_velocity_between_the_poses() -> None:
    """A camera turning at ``w`` and sliding at ``v`` (both in its frame at t = 0) for ``dt``:
    ``over(dt)`` is ``T_cw(dt) T_cw(0)^-1``."""
    from semslam.geometry.se3 import invert, so3_exp
    from semslam.slam.orb.motion_priors.base import CameraMotion

    w, v, dt = np.array([0.4, -3.0, 0.2]), np.array([0.5, 0.1, -0.2]), 0.03
    T_wc0 = make_pose(Rotation.from_euler("xyz", [10, 20, 30], degrees=True).as_matrix(), [1.0, 0.0, 2.0])
    T_wc1 = make_pose(T_wc0[:3, :3] @ so3_exp(w * dt), T_wc0[:3, 3] + T_wc0[:3, :3] @ v * dt)
    np.testing.assert_allclose(CameraMotion(w, v).over(dt), invert(T_wc1) @ T_wc0, atol=1e-12)
    turn_only = CameraMotion(w).over(dt, translation=np.array([0.01, 0.0, 0.0]))
    np.testing.assert_allclose(turn_only[:3, :3], so3_exp(-w * dt), atol=1e-12)
    np.testing.assert_allclose(turn_only[:3, 3], [0.01, 0.0, 0.0])


def _rs_case(seed: int, speed: float):  # type: ignore[no-untyped-def]
    """A rolling-shutter frame (keypoints where each row saw the points, their depths then)
    of a camera turning at 200 deg/s and sliding at ``speed``, its true motion V and the
    middle-row pixels and depths."""
    from semslam.core.types import Keypoints
    from semslam.slam.orb.frame_builders import RgbdFrameBuilder

    rng = np.random.default_rng(seed)
    uv = rng.uniform([40, 20], [600, 460], (60, 2))
    z = rng.uniform(1.0, 3.0, 60)
    V = _velocity(200.0, speed)
    obs, z_obs = _rolling_observations(V, CAM.backproject(uv, z))
    kps = Keypoints(xy=obs.astype(np.float32), octave=np.zeros(60, np.int32), angle=np.zeros(60, np.float32),
                    response=np.ones(60, np.float32), descriptors=np.zeros((60, 32), np.uint8))
    cur = RgbdFrameBuilder(CAM, 40.0).build(1, DT, kps, np.zeros((480, 640), np.float32))
    cur.depth = z_obs.astype(np.float32)  # the keypoints' depths when their rows were read
    return cur, V, uv, z


def test_with_the_imu_the_rows_move_once_by_its_motion() -> None:
    """A turn starting: the motion model's velocity is still (the last interval did not turn).
    With the IMU's motion the keypoints land at the middle row's pixels and depths before any
    match, and no refinement redoes it; before the IMU knows a velocity its rotation and the
    motion model's translation move them, and the refinement runs as without an IMU; without
    an IMU the motion model leaves them sheared."""
    from types import SimpleNamespace

    from semslam.config.schema import SlamConfig
    from semslam.core.types import Frame
    from semslam.slam.orb.motion_priors.base import CameraMotion, FrameImages, MotionState, Stage
    from semslam.slam.orb.motion_priors.rolling_shutter import RollingShutter

    cfg = SlamConfig(rolling_shutter_ms=READOUT * 1e3, rolling_shutter_global_depth=False,
                     rolling_shutter_solve=False)  # the refinement from the tracked pose, no map to fit to
    images = FrameImages(Frame(1, DT, np.zeros((480, 640, 3), np.uint8)), None)
    last = SimpleNamespace(timestamp=0.0, T_cw=np.eye(4))
    still = make_pose(np.eye(3), np.zeros(3))
    calls: list[str] = []
    ops = SimpleNamespace(optimize=lambda f: calls.append("optimize") or 0,
                          discard_outliers=lambda f: calls.append("discard") or 0)

    cur, V, uv, z = _rs_case(4, 0.5)
    rate = -Rotation.from_matrix(V[:3, :3]).as_rotvec() / DT  # R_c1c0 = exp(-w dt)
    velocity = -V[:3, :3].T @ V[:3, 3] / DT  # t = -R v dt
    prior = RollingShutter(cfg, CAM, None, None, lambda frame, T: CameraMotion(rate, velocity))  # type: ignore[arg-type]
    state = MotionState(last, True, still, DT)  # type: ignore[arg-type]
    prior.correct(Stage.FEATURES, state, cur, False, images, None)  # type: ignore[arg-type]
    np.testing.assert_allclose(cur.xy, uv, atol=0.05)
    np.testing.assert_allclose(cur.depth, z, atol=1e-3)
    cur.T_cw = still.copy()
    prior.correct(Stage.MATCHED, state, cur, True, images, ops)  # type: ignore[arg-type]
    assert calls == [] and np.allclose(cur.xy, uv, atol=0.05)

    cur, V, uv, z = _rs_case(5, 0.5)
    slide = make_pose(np.eye(3), V[:3, 3])  # the motion model: the slide, not the turn
    prior = RollingShutter(cfg, CAM, None, None, lambda frame, T: CameraMotion(rate))  # type: ignore[arg-type]
    state = MotionState(last, True, slide, DT)  # type: ignore[arg-type]
    prior.correct(Stage.FEATURES, state, cur, False, images, None)  # type: ignore[arg-type]
    np.testing.assert_allclose(cur.xy, uv, atol=0.05)
    cur.T_cw = V.copy()
    prior.correct(Stage.MATCHED, state, cur, True, images, ops)  # type: ignore[arg-type]
    assert calls == ["optimize", "discard"]
    np.testing.assert_allclose(cur.xy, uv, atol=0.05)  # redone with the tracked motion: the same

    cur, V, uv, z = _rs_case(6, 0.0)
    RollingShutter(cfg, CAM, None, None).correct(  # type: ignore[arg-type]
        Stage.FEATURES, MotionState(last, True, still, DT), cur, False, images, None)  # type: ignore[arg-type]
    assert np.linalg.norm(cur.xy - uv, axis=1).max() > 20
