"""The pose priors' interface (``slam/motion_priors``): what each predicts, and that a prior
with nothing to go on says nothing."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from semslam.config.schema import ImuConfig, SlamConfig
from semslam.core.imu import ADIS16448, ImuCalibration, ImuSamples
from semslam.core.types import Frame
from semslam.geometry.camera import PinholeCamera
from semslam.geometry.se3 import make_pose, so3_exp
from semslam.slam.orb.motion_priors.base import Correction, FrameImages, MotionState, PosePrior, Stage
from semslam.slam.orb.motion_priors.blur_coast import BlurCoast
from semslam.slam.orb.motion_priors.constant_velocity import ConstantVelocity
from semslam.slam.orb.motion_priors.depth_odometry import DepthOdometry
from semslam.slam.orb.motion_priors.inertial import InertialPrior
from semslam.slam.orb.motion_priors.sharpness_history import SharpnessHistory

CAM = PinholeCamera(fx=535.4, fy=539.2, cx=320.1, cy=247.6, width=640, height=480)


def _images() -> FrameImages:
    rgb = np.random.default_rng(0).integers(0, 255, (480, 640, 3), np.uint8)
    return FrameImages(Frame(5, 0.2, rgb), np.ones((480, 640), np.float32))


def _last(T_cw: np.ndarray) -> SimpleNamespace:
    return SimpleNamespace(index=4, timestamp=0.1667, T_cw=T_cw)


def test_constant_velocity_predicts_the_last_motion_again() -> None:
    V = make_pose(so3_exp([0.0, 0.02, 0.01]), [0.01, 0.0, 0.003])
    T_last = make_pose(so3_exp([0.3, -0.2, 0.1]), [0.5, 0.1, -0.2])
    state = MotionState(_last(T_last), True, V, 1 / 30)  # type: ignore[arg-type]
    prediction = ConstantVelocity().predict(state, _images())
    assert prediction is not None and prediction.covariance is None
    np.testing.assert_array_equal(prediction.T_cw, V @ T_last)


def test_constant_velocity_without_a_velocity_predicts_nothing() -> None:
    state = MotionState(_last(np.eye(4)), False, None, 0.0)  # type: ignore[arg-type]
    assert ConstantVelocity().predict(state, _images()) is None
    assert ConstantVelocity().predict(MotionState(None, False, None, 0.0), _images()) is None


def test_priors_without_a_last_frame_say_nothing() -> None:
    """Blur coasting and depth odometry need the last tracked frame's images: before one,
    they neither predict nor correct."""
    cfg = SlamConfig(blur_coast_sharp_ratio=0.6, depth_odometry="rgbd")
    store_map = SimpleNamespace(store=None)
    pyramid = SimpleNamespace(scales=np.ones(8))
    sharpness = SharpnessHistory()
    priors: list[PosePrior] = [BlurCoast(cfg, CAM, store_map, pyramid, sharpness),  # type: ignore[arg-type]
                               DepthOdometry(cfg, CAM, sharpness)]
    state = MotionState(None, False, None, 0.0)
    images = _images()
    cur = SimpleNamespace(T_cw=None, timestamp=0.2)
    sharpness.begin(None)
    ops = SimpleNamespace(n_matches_inliers=0)
    for prior in priors:
        assert prior.predict(state, images) is None
        for stage in Stage:
            assert prior.correct(stage, state, cur, False, images, ops) is None  # type: ignore[arg-type]


def test_sharpness_history_compares_with_the_sharpest_counted_frame() -> None:
    history = SharpnessHistory()
    gray = np.zeros((8, 8), np.uint8)
    for measured, counts, sharp in ((10.0, True, True), (50.0, False, True), (8.0, True, False)):
        history.begin(measured)
        assert history.is_sharp(gray, 0.9) == sharp
        if not counts:
            history.exclude()  # a coasted frame is no reference
        history.end(tracked=True)
    history.begin(9.5)
    assert history.is_sharp(gray, 0.9) and not history.is_sharp(gray, 1.0)  # against 10, not 50


def _moving_inertial_prior(local_map_recovery: bool) -> tuple[InertialPrior, MotionState, FrameImages, np.ndarray]:
    """An initialised IMU prior on a body moving at 0.3 m/s along x without turning (camera =
    body), readings exactly gravity's reaction; the last frame at t = 0.4 at the origin. Also
    the pose the readings put the camera at t = 0.5."""
    cfg = ImuConfig(local_map_recovery=local_map_recovery)
    prior = InertialPrior(cfg, ImuCalibration(ADIS16448))
    t = np.linspace(0.0, 1.0, 201)
    prior.buffer.add(ImuSamples(t, np.zeros((t.size, 3)), np.tile([0.0, 0.0, 9.81], (t.size, 1))))
    prior.gravity, prior.velocity = np.array([0.0, 0.0, -9.81]), np.array([0.3, 0.0, 0.0])
    state = MotionState(SimpleNamespace(index=4, timestamp=0.4, T_cw=np.eye(4)), True, np.eye(4), 0.1)  # type: ignore[arg-type]
    rgb = np.zeros((48, 64, 3), np.uint8)
    return prior, state, FrameImages(Frame(5, 0.5, rgb), None), make_pose(np.eye(3), [-0.03, 0.0, 0.0])


def _lost_frame() -> SimpleNamespace:
    cur = SimpleNamespace(timestamp=0.5, T_cw=np.eye(4), outlier=np.ones(3, bool), cleared=False)
    cur.clear_points = lambda: setattr(cur, "cleared", True)
    return cur


def test_inertial_prior_searches_the_local_map_from_its_pose_once_blind() -> None:
    """A frame lost right after a tracked one is left to the other priors and then posed by the
    IMU alone (0.03 m on from 0.3 m/s over 0.1 s). The next one lost while blind (the motion
    model had nothing to match): the IMU's pose is where the local map is searched from, its
    stale matches dropped, and the frame left to the local map (tracked, not the IMU's pose);
    only when the local map fails too is it posed by the IMU alone. A tracked frame is left
    alone."""
    prior, state, images, expected = _moving_inertial_prior(local_map_recovery=True)
    ops = SimpleNamespace(n_matches_inliers=0)
    prediction = prior.predict(state, images)
    assert prediction is not None
    np.testing.assert_allclose(prediction.T_cw, expected, atol=1e-9)
    first = _lost_frame()
    assert prior.correct(Stage.MATCHED, state, first, False, images, ops) is None  # type: ignore[arg-type]
    assert not first.cleared
    assert prior.correct(Stage.LOCAL_MAP, state, first, False, images, ops) == Correction(tracked=True, posed=True)
    assert prior.counters()["imu_only_frames"] == 1
    # The next frame, blind (the same readings and last pose keep the expected pose simple).
    assert prior.predict(state, images) is not None
    cur = _lost_frame()
    assert prior.correct(Stage.MATCHED, state, cur, True, images, ops) is None  # type: ignore[arg-type]
    assert not cur.cleared
    searched = prior.correct(Stage.MATCHED, state, cur, False, images, ops)  # type: ignore[arg-type]
    assert searched == Correction(tracked=True, posed=False)
    np.testing.assert_allclose(cur.T_cw, expected, atol=1e-9)
    assert cur.cleared and not cur.outlier.any()
    assert prior.counters()["imu_local_map_searches"] == 1
    alone = prior.correct(Stage.LOCAL_MAP, state, cur, False, images, ops)  # type: ignore[arg-type]
    assert alone == Correction(tracked=True, posed=True)
    assert prior.counters()["imu_only_frames"] == 2


def test_inertial_prior_without_local_map_recovery_poses_lost_frames_itself() -> None:
    prior, state, images, expected = _moving_inertial_prior(local_map_recovery=False)
    prior.blind_since = 0.3  # the frame before was posed by the IMU alone too
    assert prior.predict(state, images) is not None
    ops = SimpleNamespace(n_matches_inliers=0)
    cur = _lost_frame()
    assert prior.correct(Stage.MATCHED, state, cur, False, images, ops) is None  # type: ignore[arg-type]
    assert not cur.cleared
    assert prior.correct(Stage.LOCAL_MAP, state, cur, False, images, ops) == Correction(tracked=True, posed=True)
    np.testing.assert_allclose(cur.T_cw, expected, atol=1e-9)
    assert prior.counters()["imu_local_map_searches"] == 0


@pytest.mark.parametrize("monocular", [False, True])
def test_a_frame_the_imu_posed_makes_a_keyframe_only_with_depths_to_map(monocular: bool) -> None:
    """Tracking's decision (its temporal condition) for a frame the IMU posed alone, but only
    with as many keypoints with a depth as start a map, and never monocular."""
    cfg = ImuConfig(keyframe_every_s=0.5)
    align = (lambda rotation, scale: None) if monocular else None
    prior = InertialPrior(cfg, ImuCalibration(ADIS16448), align, monocular, keyframe_min_depth_points=250)
    state = MotionState(None, True, None, 0.0)
    ops = SimpleNamespace(n_matches_inliers=0)
    depth = np.zeros(1000, np.float32)
    depth[:300] = 2.0
    seen = SimpleNamespace(depth=depth)
    black = SimpleNamespace(depth=np.where(np.arange(1000) < 100, 2.0, 0.0))
    for cur, wants in ((seen, True), (seen, False), (black, True)):
        expected = wants and cur is seen and not monocular
        assert prior.keyframe_wanted(state, cur, ops, lambda w=wants: w) is expected  # type: ignore[arg-type]
    off = InertialPrior(ImuConfig(), ImuCalibration(ADIS16448), keyframe_min_depth_points=250)
    assert not off.keyframe_wanted(state, seen, ops, lambda: True)  # type: ignore[arg-type]  # the default: none
