"""A rolling shutter's rows: keypoints moved to the middle row's capture time by the camera's
velocity, then that velocity refined from the tracked pose (or fitted with it); with an IMU,
by the camera's motion as the IMU measures it at the frame's time."""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from semslam.backend.rolling_shutter_pose import solve_rolling_shutter_pose
from semslam.config.schema import SlamConfig
from semslam.core.types import Frame, ScalePyramid
from semslam.geometry.camera import PinholeCamera
from semslam.geometry.rolling_shutter import row_time_fraction
from semslam.geometry.se3 import invert
from semslam.slam.orb.motion_priors.base import (
    CameraMotion, Correction, FrameImages, MotionState, PriorDefaults, Stage, TrackerOps,
)

if TYPE_CHECKING:
    from semslam.slam.orb.frame_state import FrameState
    from semslam.slam.orb.map import Map

#: Matches the joint rolling-shutter fit uses at most (its cost grows with them).
RS_SOLVE_MAX_POINTS = 200


class RollingShutter(PriorDefaults):
    """``slam.rolling_shutter_ms`` > 0: before matching, the keypoints move by the motion
    model's velocity; after the first match (and with ``slam.rolling_shutter_solve`` again
    after the local map) by the tracked pose's, and the pose is refitted.

    With an IMU (``camera_motion``: the camera's angular rate from the gyro readings at the
    frame's time, and once the IMU is initialised its centre's velocity) the keypoints move
    once, before matching, by that motion, and stay: the visual estimates lag a turn that
    speeds up (the last interval's average) or rest on the few matches a blurred frame keeps
    (the fit). Before the IMU's initialisation its rotation replaces the motion model's in
    the first move only; then the refinement as without it. Nothing is kept between frames."""

    name = "rolling_shutter"

    def __init__(self, cfg: SlamConfig, camera: PinholeCamera, slam_map: "Map", pyramid: ScalePyramid,
                 camera_motion: Callable[[Frame, NDArray[np.float64] | None], CameraMotion | None] | None = None
                 ) -> None:
        self.cfg = cfg
        self.camera = camera
        self.map = slam_map
        self.pyr = pyramid
        # The IMU's: (frame, the last frame's T_cw or None) -> the camera's motion at the frame.
        self.camera_motion = camera_motion
        self._moved_by_imu = False  # the current frame's keypoints moved by the IMU's motion: final

    def correct(self, stage: Stage, state: MotionState, cur: "FrameState", tracked: bool,
                images: FrameImages, ops: TrackerOps) -> Correction | None:
        if stage is Stage.FEATURES:
            self._first_move(state, cur, images)
        elif tracked and not self._moved_by_imu and (stage is Stage.MATCHED or self.cfg.rolling_shutter_solve):
            self._refine(state, cur, images.depth, ops)
        return None

    def _first_move(self, state: MotionState, cur: "FrameState", images: FrameImages) -> None:
        """Before matching: by the IMU's motion where it has one (its rotation and the motion
        model's translation before it knows a velocity), else by the motion model's velocity."""
        velocity = state.velocity if state.velocity_dt > 0 else None
        last_pose = state.last.T_cw if state.tracked and state.last is not None else None
        motion = self.camera_motion(images.frame, last_pose) if self.camera_motion is not None else None
        self._moved_by_imu = motion is not None and motion.velocity is not None
        if motion is not None and (self._moved_by_imu or velocity is None):
            readout = self.cfg.rolling_shutter_ms / 1e3
            self._to_middle_row(cur, motion.over(readout), readout, images.depth)
        elif motion is not None:
            assert velocity is not None
            self._to_middle_row(cur, motion.over(state.velocity_dt, velocity[:3, 3]), state.velocity_dt, images.depth)
        elif velocity is not None:
            self._to_middle_row(cur, velocity, state.velocity_dt, images.depth)

    def _to_middle_row(self, cur: "FrameState", velocity: NDArray[np.float64], dt: float,
                       depth: NDArray[np.float32] | None) -> None:
        cur.to_middle_row(velocity, dt, self.cfg.rolling_shutter_ms / 1e3, self.camera, self.cfg.bf,
                          depth if self.cfg.rolling_shutter_global_depth else None)

    def _refine(self, state: MotionState, cur: "FrameState", depth: NDArray[np.float32] | None,
                ops: TrackerOps) -> None:
        """Redo the rolling-shutter move with a better velocity and refit the pose on the
        moved keypoints. The velocity is the tracked pose's (from the last frame to this
        one), or with ``slam.rolling_shutter_solve`` the one fitted jointly with the pose to
        the raw matches (``backend/rolling_shutter_pose.py``): the previous interval's
        average is wrong while a turn speeds up or slows down."""
        last = state.last
        # Only from a tracked last frame: a lost one keeps a stale pose, and the "velocity" to
        # it (a relocalisation's pose against it) would move every keypoint by a wrong amount.
        if (not self.cfg.rolling_shutter_refine or cur.T_cw is None or not state.tracked
                or last is None or last.T_cw is None or cur.timestamp <= last.timestamp):
            return
        dt = cur.timestamp - last.timestamp
        velocity = cur.T_cw @ invert(last.T_cw)
        if self.cfg.rolling_shutter_solve:
            velocity = self._solve_velocity(cur, velocity, dt)
        self._to_middle_row(cur, velocity, dt, depth)
        ops.optimize(cur)
        ops.discard_outliers(cur)

    def _solve_velocity(self, cur: "FrameState", guess: NDArray[np.float64], dt: float) -> NDArray[np.float64]:
        """The frame's velocity fitted with its pose to the raw keypoints of its matches."""
        assert cur.T_cw is not None
        idx = cur.matched_indices(self.map.store)
        idx = idx[~cur.outlier[idx]]
        if len(idx) < 20:
            return guess
        if len(idx) > RS_SOLVE_MAX_POINTS:  # 12 unknowns: a spread subset fixes them as well
            idx = idx[np.linspace(0, len(idx) - 1, RS_SOLVE_MAX_POINTS).astype(np.intp)]
        raw = cur.raw_xy[idx]
        frac = row_time_fraction(cur.keypoints.xy[idx, 1], int(round(self.camera.image_size[1])),
                                 self.cfg.rolling_shutter_ms / 1e3, dt)
        res = solve_rolling_shutter_pose(cur.T_cw, guess, self.map.store.pos[cur.points.rows[idx]], raw, frac,
                                         self.pyr.inv_sigma2[cur.keypoints.octave[idx]],
                                         (self.camera.fx, self.camera.fy, self.camera.cx, self.camera.cy))
        return res.velocity_cw
