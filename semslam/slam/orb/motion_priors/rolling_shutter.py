"""A rolling shutter's rows: keypoints moved to the middle row's capture time by the camera's
velocity, then that velocity refined from the tracked pose (or fitted with it)."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from semslam.backend.rolling_shutter_pose import solve_rolling_shutter_pose
from semslam.config.schema import SlamConfig
from semslam.core.types import ScalePyramid
from semslam.geometry.camera import PinholeCamera
from semslam.geometry.rolling_shutter import row_time_fraction
from semslam.geometry.se3 import invert
from semslam.slam.orb.motion_priors.base import (
    Correction, FrameImages, MotionState, PriorDefaults, Stage, TrackerOps,
)

if TYPE_CHECKING:
    from semslam.slam.orb.frame_state import FrameState
    from semslam.slam.orb.map import Map

#: Matches the joint rolling-shutter fit uses at most (its cost grows with them).
RS_SOLVE_MAX_POINTS = 200


class RollingShutter(PriorDefaults):
    """``slam.rolling_shutter_ms`` > 0: before matching, the keypoints move by the motion
    model's velocity; after the first match (and with ``slam.rolling_shutter_solve`` again
    after the local map) by the tracked pose's, and the pose is refitted. Nothing is kept:
    each frame starts from the motion state's velocity."""

    name = "rolling_shutter"

    def __init__(self, cfg: SlamConfig, camera: PinholeCamera, slam_map: "Map", pyramid: ScalePyramid) -> None:
        self.cfg = cfg
        self.camera = camera
        self.map = slam_map
        self.pyr = pyramid

    def correct(self, stage: Stage, state: MotionState, cur: "FrameState", tracked: bool,
                images: FrameImages, ops: TrackerOps) -> Correction | None:
        if stage is Stage.FEATURES:
            if state.velocity is not None and state.velocity_dt > 0:
                self._to_middle_row(cur, state.velocity, state.velocity_dt, images.depth)
        elif tracked and (stage is Stage.MATCHED or self.cfg.rolling_shutter_solve):
            self._refine(state, cur, images.depth, ops)
        return None

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
