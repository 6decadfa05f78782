"""Depth odometry on blurred frames (``slam.depth_odometry``): the frame's rotation aligned
densely against the last frame's image and depth (``backend/depth_odometry.py``), its
centre moved on at the velocity of the last well-tracked frames."""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from semslam.backend.depth_odometry import RotationOdometry, rotation_angle_deg
from semslam.config.schema import SlamConfig
from semslam.geometry.camera import PinholeCamera
from semslam.geometry.se3 import invert, orthonormalize
from semslam.slam.orb.motion_priors.base import (
    Correction, FrameImages, FrameOutcome, MotionState, PriorDefaults, Stage, TrackerOps,
)
from semslam.slam.orb.motion_priors.sharpness_history import SharpnessHistory

if TYPE_CHECKING:
    from semslam.slam.orb.frame_state import FrameState

#: Well-tracked frames whose camera centres give the velocity an aligned frame's centre
#: moves on at: one frame's centre is centimetres off on a turn's first frames.
GOOD_FRAMES = 10


class DepthOdometry(PriorDefaults):
    """Aligns a frame whose features tracked weakly, not at all, or on a fast turn; see the
    module docstring."""

    name = "depth_odometry"

    def __init__(self, cfg: SlamConfig, camera: PinholeCamera, sharpness: SharpnessHistory) -> None:
        self.cfg = cfg
        self.odometry = RotationOdometry(camera.K, cfg.depth_odometry)
        self.sharpness = sharpness
        # The last tracked frame's (index, gray, depth) to align the next against.
        self._prev: tuple[int, NDArray[np.uint8], NDArray[np.float32]] | None = None
        # (timestamp, camera centre) of the last frames the features tracked well.
        self._good_centres: deque[tuple[float, NDArray[np.float64]]] = deque(maxlen=GOOD_FRAMES)
        self._sharp = False  # this frame is sharp (only with slam.depth_odometry_sharp_ratio > 0)
        self.n_depth_odometry_frames = 0
        self.n_depth_odometry_runs = 0

    def correct(self, stage: Stage, state: MotionState, cur: "FrameState", tracked: bool,
                images: FrameImages, ops: TrackerOps) -> Correction | None:
        if stage is not Stage.LOCAL_MAP:
            return None
        gray, depth = images.frame.gray, images.depth
        if self.cfg.depth_odometry_sharp_ratio > 0:
            self._sharp = self.sharpness.is_sharp(gray, self.cfg.depth_odometry_sharp_ratio)
        if depth is None or not self._due(state, tracked, cur.T_cw, ops):
            return None
        ok, posed = self._track(state, cur, gray, depth, tracked, ops)
        return Correction(ok, posed)

    def _due(self, state: MotionState, ok: bool, cur_T: NDArray[np.float64] | None, ops: TrackerOps) -> bool:
        """Dense alignment for this frame: the last frame was tracked and its images are
        kept, and the features tracked weakly or not at all, or the camera turns fast
        (predicted or tracked), which is where blur makes a few wrong matches look like a
        good pose."""
        last, prev = state.last, self._prev
        if not state.tracked or last is None or last.T_cw is None or prev is None or prev[0] != last.index:
            return False
        if not ok:
            return True
        if self._sharp:  # slam.depth_odometry_sharp_ratio > 0: features on a sharp image are
            return False  # believed (a rolling shutter's skew biases the alignment, not them)
        if ops.n_matches_inliers < self.cfg.depth_odometry_below:
            return True
        fast = self.cfg.depth_odometry_turn_deg
        return ((state.velocity is not None and rotation_angle_deg(state.velocity) > fast)
                or (cur_T is not None and rotation_angle_deg(cur_T @ invert(last.T_cw)) > fast))

    def _guess(self, state: MotionState, cur_t: float) -> NDArray[np.float64]:
        """The frame's pose to align from: the motion model's rotation, the camera centre
        moved on at the velocity of the last frames the features tracked well (a weak
        frame's translation can be centimetres off, and the alignment keeps it)."""
        last = state.last
        assert last is not None and last.T_cw is not None
        guess = state.velocity @ last.T_cw if state.velocity is not None else last.T_cw.copy()
        c = invert(last.T_cw)[:3, 3]
        good = self._good_centres
        if len(good) >= 2 and good[-1][0] > good[0][0]:
            v = (good[-1][1] - good[0][1]) / (good[-1][0] - good[0][0])
            c = c + v * (cur_t - last.timestamp)
        guess = guess.copy()
        guess[:3, 3] = -guess[:3, :3] @ c
        return guess

    def _track(self, state: MotionState, cur: "FrameState", gray: NDArray[np.uint8], depth: NDArray[np.float32],
               ok: bool, ops: TrackerOps) -> tuple[bool, bool]:
        """The frame's rotation aligned densely against the last frame (translation: see
        ``_guess``). Features that agree with it keep their pose untouched; else the local
        map is searched again from the aligned pose, and if the features still disagree (or
        find too little) the frame keeps the aligned pose and the matches it explains.
        ``(tracked, pose from the alignment)``."""
        last, prev = state.last, self._prev
        assert last is not None and last.T_cw is not None and prev is not None
        guess = self._guess(state, cur.timestamp)
        rel = self.odometry.relative(prev[1], prev[2], gray, depth, last.T_cw @ invert(guess))
        if rel is None:
            return ok, False
        self.n_depth_odometry_runs += 1
        T_odo = orthonormalize(invert(rel) @ last.T_cw)
        max_deg = self.cfg.depth_odometry_max_deg
        if ok and cur.T_cw is not None and rotation_angle_deg(cur.T_cw @ invert(T_odo)) <= max_deg:
            return True, False
        cur.clear_points()
        cur.outlier[:] = False
        cur.T_cw = T_odo.copy()
        # A frame turning slowly is sharp: its features are believed once they track
        # (a long aligned stretch drifts from the map by more than max_deg).
        sharp = self._sharp or rotation_angle_deg(rel) <= self.cfg.depth_odometry_turn_deg
        if ops.track_local_map(cur) and (sharp or rotation_angle_deg(cur.T_cw @ invert(T_odo)) <= max_deg):
            return True, False
        # Blurred: keep the aligned pose and the matches it explains (the next frame's motion
        # model searches around their points).
        cur.T_cw = T_odo
        ops.keep_matches_consistent(cur)
        self.n_depth_odometry_frames += 1
        return True, True

    def keyframe_wanted(self, state: MotionState, cur: "FrameState", ops: TrackerOps,
                        orb_slam_wants: Callable[[], bool]) -> bool:
        """An aligned frame makes a keyframe only while it turns slowly (sharp but seeing
        little of the map: a new view), then also with few matches."""
        if state.velocity is None or rotation_angle_deg(state.velocity) > self.cfg.depth_odometry_keyframe_deg:
            return False
        return orb_slam_wants() or ops.n_matches_inliers <= 15

    def counters(self) -> dict[str, int]:
        return {"depth_odometry_frames": self.n_depth_odometry_frames,
                "depth_odometry_runs": self.n_depth_odometry_runs}

    def update(self, outcome: FrameOutcome) -> None:
        if outcome.tracked and not outcome.started_map and outcome.posed_by is not self \
                and outcome.n_inliers >= self.cfg.depth_odometry_below:
            assert outcome.centre is not None
            self._good_centres.append((outcome.frame.timestamp, outcome.centre))
        depth = outcome.images.depth
        self._prev = ((outcome.frame.index, outcome.images.frame.gray, depth)
                      if outcome.tracked and depth is not None else None)
