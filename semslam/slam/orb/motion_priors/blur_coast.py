"""Blurred frames on fast turns (``slam.blur_coast_sharp_ratio`` > 0): the turn measured from
the shift of small images (``frontend/shift_rotation.py``) predicts the pose the motion
model searches from, and a frame whose features cannot be believed coasts: its centre from
the steady motion, its rotation fitted to its matches about that centre
(``geometry/rotation_about_centre.py``). Sharp frames track as ORB-SLAM2 does (to the byte).
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from semslam.backend.depth_odometry import rotation_angle_deg
from semslam.config.schema import SlamConfig
from semslam.core.types import ScalePyramid
from semslam.frontend.shift_rotation import ShiftRotation, small_image
from semslam.geometry.camera import PinholeCamera
from semslam.geometry.rotation_about_centre import fit_rotation_about_centre
from semslam.geometry.se3 import invert
from semslam.slam.orb.motion_priors.base import (Correction, FrameImages, FrameOutcome, MotionState, PosePrediction,
                                                 Stage, TrackerOps)
from semslam.slam.orb.motion_priors.sharpness_history import SharpnessHistory

if TYPE_CHECKING:
    from semslam.slam.orb.frame_state import FrameState
    from semslam.slam.orb.map import KeyFrame, Map

#: Steady frames whose camera centres give the velocity a coasted frame's centre moves on
#: at: one frame's centre is centimetres off on a turn's first frames.
STEADY_FRAMES = 10
#: A blurred frame's features keep their matches for the coast's rotation fit when their own
#: pose turned within this many degrees of the images' shift (else they are searched again).
COAST_AGREE_DEG = 2.0
#: A coast needs its rotation to hold on this many matches; fewer, and the frame is lost as
#: ORB-SLAM2 would lose it.
COAST_MIN_INLIERS = 10
#: ...and a frame that continues a coast run (the one before it held) this many: a glance's
#: most blurred frames, turning into a view where the map is thin, keep fewer, and losing
#: them loses the frames after until the atlas starts a new map. Three bearings fix a
#: rotation; six give it redundancy against a wrong match (the fit's own default). With
#: fewer, such a frame keeps the images' shift's rotation (no matches): a glance into a view
#: the map does not cover yet.
COAST_CONTINUE_MIN_INLIERS = 6
#: A fast-turning frame whose features put the camera centre this far (metres) from where the
#: steady motion says it is coasts even when sharp: a hand-held camera does not move 3 cm in
#: a frame's time (1 m/s at 30 Hz), a 6-DoF fit on a turning frame's few matches does.
COAST_CENTRE_JUMP_M = 0.03
#: A coast run whose frames have been sharp and turning slowly for this many frames in a row
#: makes a keyframe at the last one's coasted pose. The glance has ended in a view the map
#: barely covers; the coast holds its rotation on 20-35 matches there, too few for the
#: features' own pose (the motion model needs 20 from the last frame, the local map 30), so
#: without a keyframe every frame coasts until blur_coast_max_frames and then is lost. Never
#: on the first calm frames: a keyframe at a coasted pose carries the coast's centre error
#: into the map, and the features usually find the map again within two frames.
COAST_SETTLED_FRAMES = 3

Trajectory = list[tuple[float, "KeyFrame", NDArray[np.float64]]]


class BlurCoast:
    """The images' shift as a pose prediction on blurred frames, and coasting; see the module
    docstring."""

    name = "blur_coast"

    def __init__(self, cfg: SlamConfig, camera: PinholeCamera, slam_map: "Map", pyramid: ScalePyramid,
                 sharpness: SharpnessHistory) -> None:
        self.cfg = cfg
        self.camera = camera
        self.map = slam_map
        self.pyr = pyramid
        self.sharpness = sharpness
        self.shift = ShiftRotation(camera.fx, camera.fy)
        # The last tracked frame's (index, image), and this frame's turn (deg) from the
        # images' shift and the pose it predicts (None when not measured).
        self._prev_gray: tuple[int, NDArray[np.uint8]] | None = None
        self._shift_turn_deg: float | None = None
        self._shift_prediction: NDArray[np.float64] | None = None
        # Frames in a row kept on the motion's centre, the centres of the last steady frames.
        self.coasting = 0
        self._calm_coasted = 0
        self._settled = False
        self._steady_centres: deque[tuple[float, NDArray[np.float64]]] = deque(maxlen=STEADY_FRAMES)
        # The coast under way: the steady frame before it (timestamp, centre) and the
        # trajectory entries of its frames, re-posed once features track again.
        self._coast_from: tuple[float, NDArray[np.float64]] | None = None
        self._coast_run: list[int] = []
        self.n_coasted_frames = 0
        self.n_coast_keyframes = 0
        self.n_coast_shift_only = 0

    # ------------------------------------------------------------------ prediction
    def predict(self, state: MotionState, images: FrameImages) -> PosePrediction | None:
        """On a blurred frame, or while coasting, the turn since the last tracked frame from
        the images' shift, and the pose it predicts: rotation from the shift, centre from the
        steady motion. Offered to the motion model only when the turn is fast (the constant
        velocity is wrong while a turn speeds up or slows down)."""
        self._measure(state, images.frame.gray, images.frame.timestamp)
        if self._shift_prediction is not None and self._shift_says_fast():
            return PosePrediction(self._shift_prediction.copy())
        return None

    def _measure(self, state: MotionState, gray: NDArray[np.uint8], cur_t: float) -> None:
        self._shift_turn_deg = None
        self._shift_prediction = None
        self.sharpness.of(gray)
        last, prev = state.last, self._prev_gray
        if (not state.tracked or last is None or last.T_cw is None or prev is None
                or prev[0] != last.index or prev[1].shape != gray.shape or len(self._steady_centres) < 2):
            return
        if not self.coasting and self.sharpness.is_sharp(gray, self.cfg.blur_coast_sharp_ratio):
            return
        shift = self.shift.shift_px(small_image(prev[1]), small_image(gray))
        if shift is None:
            return
        R_lc = self.shift.relative_rotation(*shift)
        self._shift_turn_deg = float(np.degrees(np.arccos(np.clip((np.trace(R_lc) - 1.0) / 2.0, -1.0, 1.0))))
        T = np.eye(4)
        T[:3, :3] = R_lc.T @ last.T_cw[:3, :3]
        T[:3, 3] = -T[:3, :3] @ self._steady_centre(cur_t)
        self._shift_prediction = T

    def _shift_says_fast(self) -> bool:
        return self._shift_turn_deg is not None and self._shift_turn_deg > self.cfg.blur_coast_turn_deg

    def _steady_centre(self, cur_t: float) -> NDArray[np.float64]:
        """The camera centre at ``cur_t`` moved on from the last steady frame at the velocity
        of the last steady frames (a least-squares line through their centres)."""
        times = np.array([t for t, _ in self._steady_centres])
        centres = np.array([c for _, c in self._steady_centres])
        dt = times - times[-1]
        if len(times) < 2 or np.ptp(dt) <= 0:
            return centres[-1].copy()
        A = np.column_stack([np.ones_like(dt), dt])
        coef, *_ = np.linalg.lstsq(A, centres, rcond=None)
        return centres[-1] + coef[1] * (cur_t - times[-1])

    # ------------------------------------------------------------------ coasting
    def correct(self, stage: Stage, state: MotionState, cur: "FrameState", tracked: bool,
                images: FrameImages, ops: TrackerOps) -> Correction | None:
        if stage is not Stage.LOCAL_MAP:
            return None
        gray = images.frame.gray
        if not self._coast_wanted(state, gray, cur, tracked):
            self.coasting = 0
            return None
        if not self._coast(state, cur, tracked, ops):
            return Correction(tracked=False)
        self.sharpness.exclude()
        self._settled = self._coast_settled(gray)
        return Correction(tracked=True, posed=True)

    def _coast_wanted(self, state: MotionState, gray: NDArray[np.uint8], cur: "FrameState", ok: bool) -> bool:
        """Coast a frame whose turn was measured (blurred, or right after a coast) when its
        features found no pose; a blurred one when the images' shift says the camera turns
        fast or its features put the centre more than COAST_CENTRE_JUMP_M from the steady
        motion's (a slide along a far wall, seen on a glance's first, slowly turning frame
        too); a sharp one only when both hold. A sharp frame turning slowly after a glance is
        believed even when its centre jumped: the view the turn ended on needs its keyframe,
        which a coasted frame does not make. Never more than blur_coast_max_frames in a row."""
        pred = self._shift_prediction
        if not state.tracked or pred is None or self.coasting >= self.cfg.blur_coast_max_frames:
            return False
        if not ok or cur.T_cw is None:
            return True
        jump = float(np.linalg.norm(invert(cur.T_cw)[:3, 3] - invert(pred)[:3, 3])) > COAST_CENTRE_JUMP_M
        if self.sharpness.is_sharp(gray, self.cfg.blur_coast_sharp_ratio):
            return jump and self._shift_says_fast()
        return self._shift_says_fast() or jump

    def _coast(self, state: MotionState, cur: "FrameState", ok: bool, ops: TrackerOps) -> bool:
        """Pose a frame the features cannot: centre from the steady motion, rotation fitted to
        its matches about that centre, starting from the images' shift. The features' own
        matches are used when their pose turned as the shift says; else the local map is
        searched from the prediction. False (lost) when fewer than COAST_MIN_INLIERS matches
        hold the rotation on the first frame of a run; on a frame that continues one, fewer
        than COAST_CONTINUE_MIN_INLIERS leave it the shift's rotation."""
        last, pred = state.last, self._shift_prediction
        assert last is not None and last.T_cw is not None and pred is not None
        centre = invert(pred)[:3, 3]
        agree = (ok and cur.T_cw is not None
                 and rotation_angle_deg(cur.T_cw[:3, :3] @ pred[:3, :3].T) <= COAST_AGREE_DEG)
        if not agree:
            cur.clear_points()
            cur.outlier[:] = False
            cur.T_cw = pred.copy()
            ops.track_local_map(cur)  # its matches are what counts here, not its pose
        assert cur.T_cw is not None
        idx = cur.matched_indices(self.map.store)
        idx = idx[~cur.outlier[idx]] if agree else idx
        fit = fit_rotation_about_centre(self.map.store.pos[cur.points.rows[idx]], centre, cur.xy[idx],
                                        self.camera.K, pred[:3, :3],
                                        self.pyr.scales[cur.keypoints.octave[idx]],
                                        min_inliers=COAST_CONTINUE_MIN_INLIERS if self.coasting else COAST_MIN_INLIERS)
        R_cw = fit.R_cw
        if not fit.ok:
            if not self.coasting:  # nothing in the image agrees (a covered lens): lost, as without the option
                return False
            # A glance into a view the map does not cover yet: its matches ran out, its
            # rotation is the images' shift's, until the features find the map again.
            R_cw = pred[:3, :3]
            cur.clear_points()
            cur.outlier[:] = False
            self.n_coast_shift_only += 1
        T = np.eye(4)
        T[:3, :3] = R_cw
        T[:3, 3] = -R_cw @ centre
        cur.T_cw = T
        ops.keep_matches_consistent(cur)
        if self.coasting == 0:
            self._coast_from = self._steady_centres[-1]
            self._coast_run.clear()
            self._calm_coasted = 0
        self.coasting += 1
        self.n_coasted_frames += 1
        return True

    def _coast_settled(self, gray: NDArray[np.uint8]) -> bool:
        """True on the COAST_SETTLED_FRAMES-th coasted frame in a row that is sharp and turns
        slowly (the shift says under blur_coast_turn_deg): the glance has ended in a view the
        map barely covers, where the features keep failing, so this frame makes a keyframe at
        its coasted pose."""
        calm = self.sharpness.is_sharp(gray, self.cfg.blur_coast_sharp_ratio) and not self._shift_says_fast()
        self._calm_coasted = self._calm_coasted + 1 if calm else 0
        return self._calm_coasted == COAST_SETTLED_FRAMES

    def keyframe_wanted(self, state: MotionState, cur: "FrameState", ops: TrackerOps,
                        orb_slam_wants: Callable[[], bool]) -> bool:
        """Only once the coast has settled (``_coast_settled``)."""
        return self._settled

    # ------------------------------------------------------------------ after the frame
    def map_aligned(self, rotation: NDArray[np.float64], scale: float) -> None:
        self._steady_centres = deque(((t, scale * rotation @ c) for t, c in self._steady_centres), maxlen=STEADY_FRAMES)
        if self._coast_from is not None:
            self._coast_from = (self._coast_from[0], scale * rotation @ self._coast_from[1])

    def counters(self) -> dict[str, int]:
        return {"coasted_frames": self.n_coasted_frames, "coast_keyframes": self.n_coast_keyframes,
                "coasted_on_shift_only": self.n_coast_shift_only}

    def update(self, outcome: FrameOutcome) -> None:
        coasted = outcome.posed_by is self
        if outcome.started_map:
            pass
        elif outcome.tracked:
            velocity = outcome.velocity
            if not coasted and (velocity is None or rotation_angle_deg(velocity) <= self.cfg.blur_coast_turn_deg):
                assert outcome.centre is not None
                self._steady_centres.append((outcome.frame.timestamp, outcome.centre))
            self.n_coast_keyframes += coasted and outcome.is_keyframe
        else:
            self._steady_centres.clear()
            self._coast_run.clear()
        if outcome.recorded_at is not None:
            if self.coasting:
                self._coast_run.append(outcome.recorded_at)
            elif self._coast_run:
                assert outcome.frame.T_cw is not None
                self._bridge_coast(outcome.trajectory, outcome.frame.timestamp, invert(outcome.frame.T_cw)[:3, 3])
        self._prev_gray = (outcome.frame.index, outcome.images.frame.gray) if outcome.tracked else None

    def _bridge_coast(self, trajectory: Trajectory, t_after: float, c_after: NDArray[np.float64]) -> None:
        """Features track again after a coast: move the coasted frames' camera centres onto
        the line between the steady frames either side (in time), keeping their rotations.
        Extrapolated centres drift (a velocity a few cm/s off over a third of a second);
        the interpolation is off by at most a/8 T^2 (under 5 mm for a hand-held camera's
        ~0.4 m/s^2 over 0.3 s). The trajectory written at the end has these; the live
        poses of those frames were the extrapolation."""
        run, self._coast_run = self._coast_run, []
        if self._coast_from is None or t_after <= self._coast_from[0]:
            return
        t_before, c_before = self._coast_from
        for k in run:
            t, ref, T_c_ref = trajectory[k]
            T_cw = T_c_ref @ ref.T_cw
            c = c_before + (t - t_before) / (t_after - t_before) * (c_after - c_before)
            T_cw[:3, 3] = -T_cw[:3, :3] @ c
            trajectory[k] = (t, ref, T_cw @ ref.T_wc)
