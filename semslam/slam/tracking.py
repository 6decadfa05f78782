"""ORB-SLAM2 tracking for RGB-D: motion model or reference keyframe, then the local map,
pose-only optimisation after each matching step, keyframe decision, relocalisation.

The thresholds are ORB-SLAM2's (Tracking.cc); where this code simplifies, a comment says so.
"""

from __future__ import annotations

import time
from collections import deque
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import cv2
import numpy as np
from numpy.typing import NDArray

from semslam.backend.depth_odometry import RotationOdometry, rotation_angle_deg
from semslam.frontend.sharpness import sharpness
from semslam.frontend.shift_rotation import ShiftRotation, small_image
from semslam.geometry.rotation_about_centre import fit_rotation_about_centre
from semslam.backend.pose_only import optimize_pose
from semslam.backend.rolling_shutter_pose import solve_rolling_shutter_pose
from semslam.config import SystemConfig
from semslam.core.protocols import DepthSource, DynamicStage, Extractor, FramePacket, MotionPrior
from semslam.core.types import TrackingState, TrackResult
from semslam.dynamics.masks import keypoints_in_mask
from semslam.dynamics.multiview import pick_references
from semslam.geometry.camera import PinholeCamera
from semslam.geometry.rolling_shutter import row_time_fraction
from semslam.geometry.se3 import invert, orthonormalize
from semslam.slam.frame_state import FrameState
from semslam.slam.keyframe_worker import KeyframeSink
from semslam.slam.map import KeyFrame, Map, update_normals_and_depths
from semslam.slam.row_kernels import first_seen_unique
from semslam.slam.search import project, rotation_consistent, search_by_bow, search_by_projection

if TYPE_CHECKING:
    from semslam.place.database import KeyframeDatabase
    from semslam.slam.atlas import Atlas
    from semslam.place.vocabulary import Vocabulary


#: The longest gap (seconds) between the last frame tracked in one map and a relocalisation
#: in another over which the motion model still bridges the two (``Tracking._bridge_to``).
BRIDGE_MAX_GAP_S = 0.5
#: Matches the joint rolling-shutter fit uses at most (its cost grows with them).
RS_SOLVE_MAX_POINTS = 200
#: The multi-view check picks its reference keyframes among the reference keyframe and this
#: many minus one of its best covisibles.
MULTIVIEW_CANDIDATES = 30
#: Well-tracked frames whose camera centres give the velocity a blurred frame's translation
#: is carried on with (one frame's is centimetres off on a turn's first frames).
CENTRE_VELOCITY_FRAMES = 10
#: A blurred frame's features keep their matches for the coast's rotation fit when their own
#: pose turned within this many degrees of the images' shift (else they are searched again).
COAST_AGREE_DEG = 2.0
#: A coast needs its rotation to hold on this many matches; fewer, and the frame is lost as
#: ORB-SLAM2 would lose it.
COAST_MIN_INLIERS = 10
#: ...and a frame that continues a coast run (the one before it held) this many: a glance's
#: most blurred frames, turning into a view where the map is thin, keep fewer. walking_hard
#: frame 156 held on 11 matches in a sequential run and on 8 in threaded ones (local mapping
#: behind), which then lost 30 frames until the atlas started a new map (threaded runs losing
#: frames: 4 of 8 -> 3 of 14; --sequential the same bytes). Three bearings fix a rotation;
#: six give it redundancy against a wrong match (the fit's own default). With fewer, such a
#: frame keeps the images' shift's rotation (no matches): a glance into a view the map does
#: not cover yet (walking_hard seed 21, the first glance: 12, 8, 7, 5 matches, then 7 frames
#: lost --sequential; with the shift's rotation 0 lost, 1.36 -> 1.00 cm).
COAST_CONTINUE_MIN_INLIERS = 6
#: A fast-turning frame whose features put the camera centre this far (metres) from where the
#: steady motion says it is coasts even when sharp: a hand-held camera does not move 3 cm in
#: a frame's time (1 m/s at 30 Hz), a 6-DoF fit on a turning frame's few matches does.
COAST_CENTRE_JUMP_M = 0.03
#: A coast run whose frames have been sharp and turning slowly for this many frames in a row
#: makes a keyframe at the last one's coasted pose. The glance has ended in a view the map
#: barely covers; the coast holds its rotation on 20-35 matches there, too few for the
#: features' own pose (the motion model needs 20 from the last frame, the local map 30), so
#: without a keyframe every frame coasts until blur_coast_max_frames and then is lost until
#: the atlas starts a new map (threaded walking_hard: 30 frames lost in 2 of 3 runs pinned
#: to one core). Never on the first calm frames: a keyframe at a coasted pose carries the
#: coast's centre error into the map (on every calm coasted frame: --sequential 1.00 ->
#: 2.58 cm), and the features usually find the map again within two frames.
COAST_SETTLED_FRAMES = 3


@dataclass(frozen=True)
class LastTracked:
    """The last frame tracking had (state OK), for bridging a relocalisation into another map."""

    timestamp: float
    T_cw: NDArray[np.float64]
    velocity: NDArray[np.float64] | None
    velocity_dt: float
    map_id: int


class Tracking:
    """Owns the current frame and decides when to make keyframes; see the module docstring."""

    def __init__(self, config: SystemConfig, camera: PinholeCamera, slam_map: Map, vocabulary: "Vocabulary",
                 database: "KeyframeDatabase", extractor: Extractor, keyframes: KeyframeSink,
                 depth: DepthSource, dynamics: DynamicStage | None, atlas: "Atlas | None" = None) -> None:
        self.cfg = config.slam
        self.dyn = config.dynamics
        self.camera = camera
        self.map = slam_map
        self.voc = vocabulary
        self.db = database
        self.extractor = extractor
        # Matching thresholds and per-level tables come from what the extractor really makes.
        self.spec = self.extractor.spec
        if self.spec != slam_map.spec:
            raise ValueError(f"the map holds {slam_map.spec} features, "
                             f"the extractor makes {self.spec}")
        self.pyr = self.spec.pyramid
        # Where new keyframes go (local mapping, or only the place database when it is off);
        # tracking also asks it whether it is idle (ORB-SLAM's AcceptKeyFrames).
        self.keyframes = keyframes
        self.depth = depth
        self.dynamics = dynamics
        self.seed = config.seed
        self.th_depth_m = self.cfg.bf * self.cfg.th_depth / camera.fx
        self.state = TrackingState.NOT_INITIALIZED
        self.last: FrameState | None = None
        self.velocity: NDArray[np.float64] | None = None
        self._last_ok: LastTracked | None = None
        self.velocity_dt = 0.0  # seconds between the two frames the velocity was measured on
        self.ref_kf: KeyFrame | None = None
        self.last_kf_frame = -1
        self.last_reloc_frame = -(10**9)
        self.local_kfs: list[KeyFrame] = []
        self.local_rows = np.zeros(0, np.intp)  # store rows of the local map's points
        self.n_relocalisations = 0
        self.n_matches_inliers = 0
        self.n_culled_dynamic_points = 0
        self._dropped: NDArray[np.bool_] | None = None  # keypoints removed as moving, this frame
        self.last_dynamic_ratio = 0.0
        # Per tracked frame: (timestamp, reference keyframe, T_c_ref) for the trajectory.
        # Lost frames have no pose and are not recorded (ORB-SLAM's SaveTrajectoryTUM skips them).
        self.trajectory_refs: list[tuple[float, KeyFrame, NDArray[np.float64]]] = []
        # Multi-map atlas (ORB-SLAM3): lost since this timestamp; a new map is wanted.
        self.atlas = atlas
        self.lost_since: float | None = None
        self.new_map_pending = False
        # Motion blur (slam.depth_odometry): the last tracked frame's (index, gray, depth) to
        # align the next against, and how many frames kept the aligned pose.
        self.odometry = (RotationOdometry(camera.K, self.cfg.depth_odometry)
                         if self.cfg.depth_odometry != "none" else None)
        self._odo_prev: tuple[int, NDArray[np.uint8], NDArray[np.float32]] | None = None
        self.n_depth_odometry_frames = 0
        # (timestamp, camera centre) of the last frames the features tracked well, for the
        # centre's velocity over them (``_odometry_guess``).
        self._good_centres: deque[tuple[float, NDArray[np.float64]]] = deque(maxlen=CENTRE_VELOCITY_FRAMES)
        self.n_depth_odometry_runs = 0
        # Sharpness (frontend/sharpness.py) of the last tracked frames, and this one's.
        self._recent_sharpness: deque[float] = deque(maxlen=CENTRE_VELOCITY_FRAMES)
        self._sharp = False  # this frame is sharp (only with slam.depth_odometry_sharp_ratio > 0)
        self._current_sharpness: float | None = None
        # Motion blur without alignment (slam.blur_coast_sharp_ratio): frames in a row kept on
        # the motion's centre, their count, and the centres of the last steady frames.
        self._coasting = 0
        self.n_coasted_frames = 0
        self.n_coast_keyframes = 0
        self.n_coast_shift_only = 0
        self._calm_coasted = 0
        self._steady_centres: deque[tuple[float, NDArray[np.float64]]] = deque(maxlen=CENTRE_VELOCITY_FRAMES)
        # The coast under way: the steady frame before it (timestamp, centre) and the
        # trajectory entries of its frames, re-posed once features track again (``_record``).
        self._coast_from: tuple[float, NDArray[np.float64]] | None = None
        self._coast_run: list[int] = []
        # The turn measured from the shift of small images (frontend/shift_rotation.py), on
        # blurred frames and while coasting only: the last tracked frame's (index, image),
        # and this frame's turn (deg) and the pose it predicts (None when not measured).
        self.shift = (ShiftRotation(camera.fx, camera.fy) if self.cfg.blur_coast_sharp_ratio > 0 else None)
        self._prev_gray: tuple[int, NDArray[np.uint8]] | None = None
        self._shift_turn_deg: float | None = None
        self._shift_prediction: NDArray[np.float64] | None = None

    def start_lost_in(self, ref_kf: KeyFrame) -> None:
        """A loaded map: start lost (the camera is nowhere until it relocalises) with this
        keyframe as the reference."""
        self.state = TrackingState.LOST
        self.ref_kf = ref_kf

    # ------------------------------------------------------------------ entry point
    def track(self, packet: FramePacket) -> TrackResult:
        self.map.tracking_idle.clear()
        try:
            return self._track(packet)
        finally:
            self.map.tracking_idle.set()

    def _track(self, packet: FramePacket) -> TrackResult:
        frame = packet.frame
        self._current_sharpness = packet.sharpness  # measured ahead by the reader, or None
        timings: dict[str, float] = {}
        dynamic, mask = None, None
        if self.dynamics is not None:
            dynamic, mask, wait_ms = self.dynamics.before_extraction(packet, self._motion_prior())
            if dynamic is not None:
                timings["semantic_wait"] = wait_ms
        t0 = time.perf_counter()
        self._dropped = None  # set by _remove_moving
        kps = self.extractor.extract(frame.gray, mask)
        packet.keypoints_xy = kps.xy
        depth = self.depth.depth(frame)
        cur = FrameState.create(frame.index, frame.timestamp, kps, depth, self.camera, self.cfg.bf)
        if self.cfg.rolling_shutter_ms > 0 and self.velocity is not None and self.velocity_dt > 0:
            self._to_middle_row(cur, self.velocity, self.velocity_dt, depth)
        timings["extract"] = (time.perf_counter() - t0) * 1e3
        is_kf = False
        t_wait = time.perf_counter()
        with self.map.lock:
            t0 = time.perf_counter()
            timings["lock_wait"] = (t0 - t_wait) * 1e3
            self._follow_atlas(frame.timestamp)
            if self.state is TrackingState.NOT_INITIALIZED or self.new_map_pending:
                ok = self._initialize(cur)
                is_kf = ok
                timings["track"] = (time.perf_counter() - t0) * 1e3
                if not ok:
                    return TrackResult(frame.timestamp, None, self.state, n_keypoints=len(kps), timings=timings)
            else:
                if self.shift is not None:
                    self._measure_blur(frame.gray, cur.timestamp)
                ok = self._track_frame(cur, timings)
                if ok:
                    self._refine_rolling_shutter(cur, depth)
                timings["track"] = (time.perf_counter() - t0) * 1e3
                if ok:
                    t0 = time.perf_counter()
                    ok = self._track_local_map(cur)
                    if ok and self.cfg.rolling_shutter_solve:
                        self._refine_rolling_shutter(cur, depth)  # again, on the local map's matches
                    timings["local_map"] = (time.perf_counter() - t0) * 1e3
                odo = coasted = False
                if self.odometry is not None and self.cfg.depth_odometry_sharp_ratio > 0:
                    self._sharp = self._is_sharp(frame.gray, self.cfg.depth_odometry_sharp_ratio)
                if self.shift is not None:
                    if self._coast_wanted(frame.gray, cur, ok):
                        ok = coasted = self._coast(cur, ok)
                    else:
                        self._coasting = 0
                if not coasted and self._odometry_due(ok, cur.T_cw, depth):
                    t0 = time.perf_counter()
                    ok, odo = self._track_with_odometry(cur, frame.gray, depth, ok)  # type: ignore[arg-type]
                    timings["depth_odometry"] = (time.perf_counter() - t0) * 1e3
                if ok and self.dyn.multiview and self.dynamics is not None and depth is not None:
                    t0 = time.perf_counter()
                    T_odo = cur.T_cw.copy() if odo or coasted else None
                    dynamic = self._remove_moving(cur, depth, dynamic)
                    if T_odo is not None:  # its refit on the few matches left would undo the alignment
                        cur.T_cw = T_odo
                        self._keep_matches_consistent(cur)
                    timings["multiview"] = (time.perf_counter() - t0) * 1e3
                self.state = TrackingState.OK if ok else TrackingState.LOST
                if ok:
                    self.velocity = cur.T_cw @ invert(self.last.T_cw) if self.last is not None and self.last.T_cw is not None else None
                    self.velocity_dt = cur.timestamp - self.last.timestamp if self.last is not None else 0.0
                    if self.odometry is not None and not odo and self.n_matches_inliers >= self.cfg.depth_odometry_below:
                        self._good_centres.append((cur.timestamp, invert(cur.T_cw)[:3, 3]))
                    if not coasted and (self.velocity is None
                                        or rotation_angle_deg(self.velocity) <= self.cfg.blur_coast_turn_deg):
                        self._steady_centres.append((cur.timestamp, invert(cur.T_cw)[:3, 3]))
                    self._last_ok = LastTracked(cur.timestamp, cur.T_cw.copy(), self.velocity, self.velocity_dt,
                                                self.map.active_map)
                    settled = coasted and self._coast_settled(frame.gray)
                    if (not self.cfg.localization_only
                            and (settled or not coasted and self._keyframe_wanted(cur, odo))):
                        t0 = time.perf_counter()
                        self._create_keyframe(cur)
                        timings["keyframe"] = (time.perf_counter() - t0) * 1e3
                        is_kf = True
                        self.n_coast_keyframes += settled
                    # Outliers are not carried to the next frame (ORB-SLAM discards them here).
                    out = np.flatnonzero(cur.outlier)
                    cur.points.put(out, [None] * out.size, np.full(out.size, -1, np.intp))
                    cur.outlier[:] = False
                else:
                    self.velocity = None
                    self._steady_centres.clear()
                    self._coast_run.clear()
                    if cur.T_cw is None:
                        cur.T_cw = self.last.T_cw.copy() if self.last is not None and self.last.T_cw is not None else np.eye(4)
            if cur.ref_kf is None:
                cur.ref_kf = self.ref_kf
            self._apply_world_change(cur)  # a merge inside this frame's keyframe (sequential)
            if self.state is TrackingState.OK:
                self._record(cur)
            self.last = cur
            if self.odometry is not None:
                self._odo_prev = ((cur.index, frame.gray, depth) if self.state is TrackingState.OK and depth is not None
                                  else None)
            if self.shift is not None:
                self._prev_gray = (cur.index, frame.gray) if self.state is TrackingState.OK else None
            if self.state is TrackingState.OK and self._current_sharpness is not None and not self._coasting:
                self._recent_sharpness.append(self._current_sharpness)
            self._current_sharpness = None
            n_inl = int(((cur.points.rows >= 0) & ~cur.outlier).sum())
        pose_wc = invert(cur.T_cw) if cur.T_cw is not None and self.state is TrackingState.OK else None
        # count_nonzero: the same value as mean() of the bool mask without its float copy (0.3 ms)
        self.last_dynamic_ratio = np.count_nonzero(dynamic) / dynamic.size if dynamic is not None else 0.0
        if dynamic is not None:
            packet.dynamic = dynamic  # the final mask (semantic + moving regions) for map builders
        packet.keypoint_static = ~self._dropped if self._dropped is not None else np.ones(len(kps), bool)
        return TrackResult(frame.timestamp, pose_wc, self.state, n_matches=n_inl, n_inliers=n_inl,
                           n_keypoints=len(kps), is_keyframe=is_kf, dynamic_ratio=self.last_dynamic_ratio,
                           timings=timings)

    # ------------------------------------------------------------------ motion blur
    def _odometry_due(self, ok: bool, cur_T: NDArray[np.float64] | None, depth: NDArray[np.float32] | None) -> bool:
        """Dense alignment for this frame: the option is on, the last frame was tracked and
        its images are kept, and the features tracked weakly or not at all, or the camera
        turns fast (predicted or tracked), which is where blur makes a few wrong matches
        look like a good pose."""
        last, prev = self.last, self._odo_prev
        if (self.odometry is None or depth is None or self.state is not TrackingState.OK or last is None
                or last.T_cw is None or prev is None or prev[0] != last.index):
            return False
        if not ok:
            return True
        if self._sharp:  # slam.depth_odometry_sharp_ratio > 0: features on a sharp image are
            return False  # believed (a rolling shutter's skew biases the alignment, not them)
        if self.n_matches_inliers < self.cfg.depth_odometry_below:
            return True
        fast = self.cfg.depth_odometry_turn_deg
        return ((self.velocity is not None and rotation_angle_deg(self.velocity) > fast)
                or (cur_T is not None and rotation_angle_deg(cur_T @ invert(last.T_cw)) > fast))

    def _sharpness(self, gray: NDArray[np.uint8]) -> float:
        """This frame's sharpness: the packet's (measured ahead by the reader), else measured
        here, once per frame."""
        if self._current_sharpness is None:
            self._current_sharpness = sharpness(gray)
        return self._current_sharpness

    def _is_sharp(self, gray: NDArray[np.uint8], ratio: float) -> bool:
        """This frame's sharpness against the sharpest of the last tracked (not coasted) frames."""
        recent = self._recent_sharpness
        return not recent or self._sharpness(gray) >= ratio * max(recent)

    def _measure_blur(self, gray: NDArray[np.uint8], cur_t: float) -> None:
        """This frame's sharpness; on a blurred frame, or while coasting, the turn since the
        last tracked frame from the images' shift, and the pose it predicts: rotation from
        the shift, centre from the steady motion. When the turn is fast the motion model
        searches from that prediction instead of the constant velocity (wrong while a turn
        speeds up or slows down). Sharp frames track as ORB-SLAM2 does (to the byte)."""
        assert self.shift is not None
        self._shift_turn_deg = None
        self._shift_prediction = None
        self._sharpness(gray)
        last, prev = self.last, self._prev_gray
        if (self.state is not TrackingState.OK or last is None or last.T_cw is None or prev is None
                or prev[0] != last.index or prev[1].shape != gray.shape or len(self._steady_centres) < 2):
            return
        if not self._coasting and self._is_sharp(gray, self.cfg.blur_coast_sharp_ratio):
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

    def _coast_wanted(self, gray: NDArray[np.uint8], cur: FrameState, ok: bool) -> bool:
        """Coast a frame whose turn was measured (blurred, or right after a coast) when its
        features found no pose; a blurred one when the images' shift says the camera turns
        fast or its features put the centre more than COAST_CENTRE_JUMP_M from the steady
        motion's (a slide along a far wall, seen on a glance's first, slowly turning frame
        too); a sharp one only when both hold. A sharp frame turning slowly after a glance is
        believed even when its centre jumped: the view the turn ended on needs its keyframe,
        and coasting it (no keyframe) left tracking without points there (6 lost frames on
        the blur-only render). Never more than blur_coast_max_frames in a row."""
        pred = self._shift_prediction
        if self.state is not TrackingState.OK or pred is None or self._coasting >= self.cfg.blur_coast_max_frames:
            return False
        if not ok or cur.T_cw is None:
            return True
        jump = float(np.linalg.norm(invert(cur.T_cw)[:3, 3] - invert(pred)[:3, 3])) > COAST_CENTRE_JUMP_M
        if self._is_sharp(gray, self.cfg.blur_coast_sharp_ratio):
            return jump and self._shift_says_fast()
        return self._shift_says_fast() or jump

    def _coast_settled(self, gray: NDArray[np.uint8]) -> bool:
        """True on the COAST_SETTLED_FRAMES-th coasted frame in a row that is sharp and turns
        slowly (the shift says under blur_coast_turn_deg): the glance has ended in a view the
        map barely covers, where the features keep failing, so this frame makes a keyframe at
        its coasted pose."""
        calm = self._is_sharp(gray, self.cfg.blur_coast_sharp_ratio) and not self._shift_says_fast()
        self._calm_coasted = self._calm_coasted + 1 if calm else 0
        return self._calm_coasted == COAST_SETTLED_FRAMES

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

    def _coast(self, cur: FrameState, ok: bool) -> bool:
        """Pose a frame the features cannot: centre from the steady motion, rotation fitted to
        its matches about that centre, starting from the images' shift. The features' own
        matches are used when their pose turned as the shift says; else the local map is
        searched from the prediction. False (lost) when fewer than COAST_MIN_INLIERS matches
        hold the rotation on the first frame of a run; on a frame that continues one, fewer
        than COAST_CONTINUE_MIN_INLIERS leave it the shift's rotation."""
        last, pred = self.last, self._shift_prediction
        assert last is not None and last.T_cw is not None and pred is not None
        centre = invert(pred)[:3, 3]
        agree = (ok and cur.T_cw is not None
                 and rotation_angle_deg(cur.T_cw[:3, :3] @ pred[:3, :3].T) <= COAST_AGREE_DEG)
        if not agree:
            cur.clear_points()
            cur.outlier[:] = False
            cur.T_cw = pred.copy()
            self._track_local_map(cur)  # its matches are what counts here, not its pose
        assert cur.T_cw is not None
        idx = cur.matched_indices(self.map.store)
        idx = idx[~cur.outlier[idx]] if agree else idx
        fit = fit_rotation_about_centre(self.map.store.pos[cur.points.rows[idx]], centre, cur.xy[idx],
                                        self.camera.K, pred[:3, :3],
                                        self.pyr.scales[cur.keypoints.octave[idx]],
                                        min_inliers=COAST_CONTINUE_MIN_INLIERS if self._coasting else COAST_MIN_INLIERS)
        R_cw = fit.R_cw
        if not fit.ok:
            if not self._coasting:  # nothing in the image agrees (a covered lens): lost, as without the option
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
        self._keep_matches_consistent(cur)
        if self._coasting == 0:
            self._coast_from = self._steady_centres[-1]
            self._coast_run.clear()
            self._calm_coasted = 0
        self._coasting += 1
        self.n_coasted_frames += 1
        return True

    def _odometry_guess(self, cur_t: float) -> NDArray[np.float64]:
        """The frame's pose to align from: the motion model's rotation, the camera centre
        moved on at the velocity of the last frames the features tracked well (a weak
        frame's translation can be centimetres off, and the alignment keeps it)."""
        last = self.last
        assert last is not None and last.T_cw is not None
        guess = self.velocity @ last.T_cw if self.velocity is not None else last.T_cw.copy()
        c = invert(last.T_cw)[:3, 3]
        good = self._good_centres
        if len(good) >= 2 and good[-1][0] > good[0][0]:
            v = (good[-1][1] - good[0][1]) / (good[-1][0] - good[0][0])
            c = c + v * (cur_t - last.timestamp)
        guess = guess.copy()
        guess[:3, 3] = -guess[:3, :3] @ c
        return guess

    def _track_with_odometry(self, cur: FrameState, gray: NDArray[np.uint8], depth: NDArray[np.float32],
                             ok: bool) -> tuple[bool, bool]:
        """The frame's rotation aligned densely against the last frame (translation: see
        ``_odometry_guess``). Features that agree with it keep their pose untouched; else the
        local map is searched again from the aligned pose, and if the features still
        disagree (or find too little) the frame keeps the aligned pose and the matches it
        explains. ``(tracked, pose from the alignment)``."""
        last, prev = self.last, self._odo_prev
        assert self.odometry is not None and last is not None and last.T_cw is not None and prev is not None
        guess = self._odometry_guess(cur.timestamp)
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
        if self._track_local_map(cur) and (sharp or rotation_angle_deg(cur.T_cw @ invert(T_odo)) <= max_deg):
            return True, False
        # Blurred: keep the aligned pose and the matches it explains (the next frame's motion
        # model searches around their points).
        cur.T_cw = T_odo
        self._keep_matches_consistent(cur)
        self.n_depth_odometry_frames += 1
        return True, True

    def _keep_matches_consistent(self, cur: FrameState, th_px: float = 5.991 ** 0.5) -> None:
        """Unmatch the keypoints whose map point projects farther than ``th_px`` (x the
        level's scale) from them under the frame's pose."""
        assert cur.T_cw is not None
        idx = cur.matched_indices(self.map.store)
        cur.outlier[:] = False
        if len(idx) == 0:
            self.n_matches_inliers = 0
            return
        uv, z = project(cur.T_cw, self.map.store.pos[cur.points.rows[idx]], self.camera.fx, self.camera.fy,
                        self.camera.cx, self.camera.cy)
        err = np.linalg.norm(uv - cur.xy[idx], axis=1)
        bad = (z <= 0) | (err > th_px * self.pyr.scales[cur.keypoints.octave[idx]])
        for i in idx[bad].tolist():
            cur.points[i] = None
        rows = cur.points.rows
        rows = rows[rows >= 0]
        self.n_matches_inliers = int((self.map.store.n_kf_obs[rows] > 0).sum())

    def _keyframe_wanted(self, cur: FrameState, odo: bool) -> bool:
        """ORB-SLAM2's decision; a frame posed by the alignment only while it turns slowly
        (sharp but seeing little of the map: a new view), then also with few matches."""
        if not odo:
            return self._need_new_keyframe(cur)
        if self.velocity is None or rotation_angle_deg(self.velocity) > self.cfg.depth_odometry_keyframe_deg:
            return False
        return self._need_new_keyframe(cur) or self.n_matches_inliers <= 15

    # ------------------------------------------------------------------ rolling shutter
    def _to_middle_row(self, cur: FrameState, velocity: NDArray[np.float64], dt: float,
                       depth: NDArray[np.float32] | None) -> None:
        cur.to_middle_row(velocity, dt, self.cfg.rolling_shutter_ms / 1e3, self.camera, self.cfg.bf,
                          depth if self.cfg.rolling_shutter_global_depth else None)

    def _refine_rolling_shutter(self, cur: FrameState, depth: NDArray[np.float32] | None) -> None:
        """Redo the rolling-shutter move with a better velocity and refit the pose on the
        moved keypoints. The velocity is the tracked pose's (from the last frame to this
        one), or with ``slam.rolling_shutter_solve`` the one fitted jointly with the pose to
        the raw matches (``backend/rolling_shutter_pose.py``): the previous interval's
        average is wrong while a turn speeds up or slows down."""
        last = self.last
        # Only from a tracked last frame: a lost one keeps a stale pose, and the "velocity" to
        # it (a relocalisation's pose against it) would move every keypoint by a wrong amount.
        if (self.cfg.rolling_shutter_ms <= 0 or not self.cfg.rolling_shutter_refine or cur.T_cw is None
                or self.state is not TrackingState.OK or last is None or last.T_cw is None
                or cur.timestamp <= last.timestamp):
            return
        dt = cur.timestamp - last.timestamp
        velocity = cur.T_cw @ invert(last.T_cw)
        if self.cfg.rolling_shutter_solve:
            velocity = self._solve_velocity(cur, velocity, dt)
        self._to_middle_row(cur, velocity, dt, depth)
        self._optimize(cur)
        self._discard_outliers(cur)

    def _solve_velocity(self, cur: FrameState, guess: NDArray[np.float64], dt: float) -> NDArray[np.float64]:
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

    # ------------------------------------------------------------------ atlas
    def _follow_atlas(self, timestamp: float) -> None:
        """Under the map lock before a frame: map the last frame into its map's new world if
        a merge moved it; once relocalisation has failed for ``slam.new_map_after_s``, ask
        for a new map, which the next frame with enough keypoints and depth starts
        (ORB-SLAM3 CreateMapInAtlas). Frames until then stay LOST."""
        if self.atlas is None:
            return
        self._apply_world_change(self.last)
        if self.state is not TrackingState.LOST or self.new_map_pending:
            self.lost_since = None
            return
        if self.lost_since is None:
            self.lost_since = self.last.timestamp if self.last is not None else timestamp
        if self.atlas.new_map_due(timestamp - self.lost_since):
            self.atlas.start_new_map()
            self.new_map_pending = True
            self.velocity = None
            self.local_kfs = []
            self.local_rows = np.zeros(0, np.intp)

    def _bridge_to(self, cur: FrameState) -> NDArray[np.float64] | None:
        """``S`` (this frame's map world <- the left map's world) if the last frame tracked in
        the left map is at most ``BRIDGE_MAX_GAP_S`` old: that frame carried by the motion
        model to now is this frame in the left map's world. A guess for loop closing, which
        verifies it (``LoopClosing._merge_on_hints``)."""
        last = self._last_ok
        if (last is None or cur.T_cw is None or last.velocity is None or last.velocity_dt <= 0
                or last.map_id != self.map.active_map):
            return None
        gap = cur.timestamp - last.timestamp
        if not 0 < gap <= BRIDGE_MAX_GAP_S:
            return None
        T_pred = last.T_cw
        for _ in range(max(1, round(gap / last.velocity_dt))):
            T_pred = last.velocity @ T_pred
        return invert(cur.T_cw) @ T_pred

    def _apply_world_change(self, frame: FrameState | None) -> None:
        """Map ``frame`` into its map's world if a merge moved that map (``Atlas``)."""
        S = self.atlas.take_world_change() if self.atlas is not None else None
        if S is not None and frame is not None and frame.T_cw is not None:
            frame.T_cw = frame.T_cw @ invert(S)

    # ------------------------------------------------------------------ dynamics
    def _motion_prior(self) -> MotionPrior | None:
        """The last frame's pose and the motion model, for a skipped frame's warped mask."""
        last = self.last
        if last is None or last.T_cw is None:
            return None
        velocity = self.velocity if self.state is TrackingState.OK else None
        return MotionPrior(last.index, last.T_cw, velocity)

    def _remove_moving(self, cur: FrameState, depth: NDArray[np.float32],
                       dynamic: NDArray[np.bool_] | None) -> NDArray[np.bool_] | None:
        """With the pose just tracked, the dynamic stage finds moving regions (DDL-SLAM's
        multi-view geometry); keypoints there (and in their border band) are dropped, the map
        points matched inside are culled and the pose re-optimised."""
        ref = self.ref_kf
        if ref is None or cur.T_cw is None or self.dynamics is None:
            return dynamic
        # Reference keyframes with the highest overlap (the reference and its best
        # covisibles), preferring those old enough for a mover to have moved since.
        cands = [k for k in (ref, *ref.best_covisibles(MULTIVIEW_CANDIDATES - 1)) if not k.bad]
        pick = pick_references([k.timestamp for k in cands], cur.timestamp, self.dyn.multiview_keyframes,
                               self.dyn.multiview_min_age_s)
        refs = [(cands[i].T_cw, cands[i].xy, cands[i].depth) for i in pick]
        regions = self.dynamics.after_pose(cur.T_cw, depth, refs)
        if regions is None:
            return dynamic
        drop = keypoints_in_mask(cur.keypoints.xy, regions.drop)
        self._dropped = drop
        if drop.any():
            # A map point matched inside a region found moving is on the mover: it was
            # mapped while the object stood still and would keep pulling the pose.
            inside = keypoints_in_mask(cur.keypoints.xy, regions.moving)
            for i in np.nonzero(inside)[0]:
                p = cur.points[i]
                if p is not None and not p.bad and not cur.outlier[i]:
                    self.map.set_bad_point(p)
                    self.n_culled_dynamic_points += 1
            cur.drop(~drop)
            self._optimize(cur)
        return regions.moving if dynamic is None else (dynamic | regions.moving)

    def _record(self, cur: FrameState) -> None:
        ref = cur.ref_kf or self.ref_kf
        if ref is None or cur.T_cw is None:
            return
        self.trajectory_refs.append((cur.timestamp, ref, cur.T_cw @ ref.T_wc))
        if self._coasting:
            self._coast_run.append(len(self.trajectory_refs) - 1)
        elif self._coast_run:
            self._bridge_coast(cur.timestamp, invert(cur.T_cw)[:3, 3])

    def _bridge_coast(self, t_after: float, c_after: NDArray[np.float64]) -> None:
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
            t, ref, T_c_ref = self.trajectory_refs[k]
            T_cw = T_c_ref @ ref.T_cw
            c = c_before + (t - t_before) / (t_after - t_before) * (c_after - c_before)
            T_cw[:3, 3] = -T_cw[:3, :3] @ c
            self.trajectory_refs[k] = (t, ref, T_cw @ ref.T_wc)

    # ------------------------------------------------------------------ initialisation
    def _initialize(self, cur: FrameState) -> bool:
        """First frame with enough keypoints becomes keyframe 0 at the origin, points from depth."""
        if len(cur) < self.cfg.min_init_keypoints or (cur.depth > 0).sum() < self.cfg.min_init_keypoints // 2:
            return False
        cur.T_cw = np.eye(4)
        kf = self._make_keyframe(cur)
        idx = np.nonzero(cur.depth > 0)[0]
        self._new_points_from_keyframe(kf, cur, idx, cur.world_points(idx, self.camera))
        self.map.add_keyframe(kf)
        self.keyframes.insert(kf)
        self.ref_kf = kf
        cur.ref_kf = kf
        self.last_kf_frame = cur.index
        self.local_kfs = [kf]
        self.local_rows = kf.points.rows[kf.points.rows >= 0]
        self.state = TrackingState.OK
        self.new_map_pending = False
        return True

    def _new_points_from_keyframe(self, kf: KeyFrame, cur: FrameState, idx: NDArray[np.intp],
                                  pos: NDArray[np.float64]) -> None:
        """Map points for keypoints ``idx`` of a new keyframe at world positions ``pos``."""
        made = []
        for i, pw in zip(idx.tolist(), pos):
            p = self.map.new_point(pw, kf.keypoints.descriptors[i], kf)
            p.add_observation(kf, i)
            kf.points[i] = p
            cur.points[i] = p
            made.append(p)
        update_normals_and_depths(made, self.pyr.scales)

    def _make_keyframe(self, cur: FrameState) -> KeyFrame:
        assert cur.T_cw is not None
        kf = KeyFrame(self.map.new_kf_id(), cur.index, cur.timestamp, cur.T_cw.copy(), cur.keypoints, cur.xy,
                      cur.depth, cur.ur, list(cur.points))
        if cur.bow is not None:
            kf.bow, kf.featvec = cur.bow, cur.featvec or {}
        return kf

    # ------------------------------------------------------------------ frame tracking
    def _track_frame(self, cur: FrameState, timings: dict[str, float]) -> bool:
        if self.state is TrackingState.OK:
            ok = False
            if self.velocity is not None and cur.index > self.last_reloc_frame + 1:
                ok = self._track_with_motion_model(cur)
            if not ok:
                ok = self._track_reference_keyframe(cur)
            return ok
        t0 = time.perf_counter()
        ok = self._relocalise(cur)
        timings["relocalise"] = (time.perf_counter() - t0) * 1e3
        if ok:
            self.n_relocalisations += 1
            self.last_reloc_frame = cur.index
        return ok

    def _optimize(self, cur: FrameState) -> int:
        """Pose-only optimisation over the frame's matched points; marks outliers."""
        idx = cur.matched_indices(self.map.store)
        if len(idx) < 3:
            return 0
        assert cur.T_cw is not None
        pts = self.map.store.pos[cur.points.rows[idx]]
        oct_ = cur.keypoints.octave[idx]
        res = optimize_pose(cur.T_cw, pts, cur.xy[idx], cur.ur[idx], self.pyr.inv_sigma2[oct_],
                            self.camera.fx, self.camera.fy, self.camera.cx, self.camera.cy, self.cfg.bf)
        cur.T_cw = orthonormalize(res.T_cw)
        cur.outlier[:] = False
        cur.outlier[idx[~res.inliers]] = True
        return int(res.inliers.sum())

    def _discard_outliers(self, cur: FrameState) -> int:
        """Unmatch the outliers; the number of matches left whose point is in a keyframe."""
        for i in np.flatnonzero(cur.outlier & (cur.points.rows >= 0)).tolist():
            cur.points[i] = None
        cur.outlier[:] = False
        rows = cur.points.rows
        rows = rows[rows >= 0]
        return int((self.map.store.n_kf_obs[rows] > 0).sum())

    def _track_with_motion_model(self, cur: FrameState) -> bool:
        last = self.last
        assert last is not None and last.T_cw is not None and self.velocity is not None
        cur.T_cw = (self._shift_prediction.copy() if self._shift_prediction is not None and self._shift_says_fast()
                    else self.velocity @ last.T_cw)
        store = self.map.store
        idx = last.matched_indices(store)
        idx = idx[~last.outlier[idx]]
        if len(idx) == 0:
            return False
        rows = last.points.rows[idx]
        pos = store.pos[rows]
        uv, z = project(cur.T_cw, pos, self.camera.fx, self.camera.fy, self.camera.cx, self.camera.cy)
        # Forward motion makes points appear at finer levels, backward at coarser (ORB-SLAM).
        t_lc = (cur.T_cw @ invert(last.T_cw))[:3, 3]
        forward = t_lc[2] > self.cfg.bf / self.camera.fx
        backward = -t_lc[2] > self.cfg.bf / self.camera.fx
        octv = last.keypoints.octave[idx].astype(np.intp)
        lo = np.where(forward, octv, np.where(backward, 0, octv - 1))
        hi = np.where(forward, self.pyr.n_levels - 1, np.where(backward, octv, octv + 1))
        for th in (15.0, 30.0):
            inside = self._inside(uv, z)
            radius = th * self.pyr.scales[octv]
            qi, ti = self._search(cur, uv[inside], radius[inside], lo[inside], hi[inside],
                                  store.descriptor[rows[inside]])
            sel = np.nonzero(inside)[0][qi]
            keep = rotation_consistent(cur.keypoints.angle[ti], last.keypoints.angle[idx[sel]])
            sel, ti = sel[keep], ti[keep]
            if len(ti) >= 20:
                break
            cur.clear_points()
        if len(ti) < 20:
            return False
        cur.points.put(ti, store.points(rows[sel]), rows[sel])
        self._optimize(cur)
        return self._discard_outliers(cur) >= 10

    def _inside(self, uv: NDArray[np.float64], z: NDArray[np.float64]) -> NDArray[np.bool_]:
        return (z > 0) & self.camera.in_image(uv)

    def _search(self, cur: FrameState, uv: NDArray[np.float64], radius: NDArray[np.float64], lo: NDArray[np.intp],
                hi: NDArray[np.intp], desc: NDArray[Any]
                ) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
        if len(uv) == 0:
            return np.zeros(0, np.intp), np.zeros(0, np.intp)
        return search_by_projection(uv, radius, lo, hi, desc, cur.xy, cur.keypoints.octave, cur.keypoints.descriptors,
                                    cur.free_mask(self.map.store), cur.grid(*self.camera.image_size), self.map.matcher,
                                    self.spec.th_high)

    def _compute_bow(self, cur: FrameState) -> None:
        if cur.bow is None:
            cur.bow, cur.featvec = self.voc.transform(cur.keypoints.descriptors)

    def _track_reference_keyframe(self, cur: FrameState) -> bool:
        """Match by bag-of-words to the reference keyframe; start from the last pose."""
        kf = self.ref_kf
        if kf is None or kf.bad or self.last is None:
            return False
        self._compute_bow(cur)
        if kf.bow is None:  # local mapping has not reached this keyframe yet (a slow machine
            # right after initialisation): without its words nothing would match and the
            # frame would be lost.
            kf.set_words(*self.voc.transform(kf.keypoints.descriptors))
        kf_valid = np.array([p is not None and not p.bad for p in kf.points], bool)
        ia, ib = search_by_bow(kf.featvec, kf.keypoints.descriptors, cur.featvec or {}, cur.keypoints.descriptors,
                               kf_valid, np.ones(len(cur), bool), self.map.matcher,
                               self.spec.th_low)
        keep = rotation_consistent(kf.keypoints.angle[ia], cur.keypoints.angle[ib])
        ia, ib = ia[keep], ib[keep]
        if len(ia) < 15:
            return False
        cur.clear_points()
        for a, b in zip(ia, ib):
            cur.points[b] = kf.points[a]
        cur.T_cw = self.last.T_cw.copy()
        self._optimize(cur)
        return self._discard_outliers(cur) >= 10

    # ------------------------------------------------------------------ local map
    def _update_local_map(self, cur: FrameState) -> None:
        """Local keyframes (those sharing points with the frame, their best covisibles,
        children and parents; ORB-SLAM UpdateLocalKeyFrames) and their points, as store
        rows in first-seen order (UpdateLocalPoints)."""
        rows = cur.points.rows[(cur.points.rows >= 0) & ~cur.outlier]
        store = self.map.store
        # Observing keyframes counted in first-seen order (the store's observer rows).
        observers, counts = store.observer_counts(rows[~store.bad[rows]])
        if not observers:
            return
        local: dict[KeyFrame, None] = {kf: None for kf in observers if not kf.bad}
        for kf in list(local)[:80]:
            for nb in kf.best_covisibles(10):
                local.setdefault(nb)
            for ch in kf.children:
                if not ch.bad:
                    local.setdefault(ch)
            if kf.parent is not None and not kf.parent.bad:
                local.setdefault(kf.parent)
        self.local_kfs = list(local)
        best = observers[int(np.argmax(counts))]  # the first of the most observed, like max()
        if not best.bad:
            self.ref_kf = best
            cur.ref_kf = best
        rows = np.concatenate([kf.points.rows for kf in self.local_kfs]) if self.local_kfs else np.zeros(0, np.intp)
        rows = first_seen_unique(rows)
        self.local_rows = rows[~self.map.store.bad[rows]]

    def _track_local_map(self, cur: FrameState) -> bool:
        """Project the local map's points into the frame, match them (SearchLocalPoints),
        optimise the pose and count the inliers (TrackLocalMap)."""
        self._update_local_map(cur)
        store = self.map.store
        frame_rows = cur.points.rows[cur.points.rows >= 0]
        frame_rows = frame_rows[~store.bad[frame_rows]]
        np.add.at(store.n_visible, frame_rows, 1)
        # Local points the frame does not already hold (a mark per store row: np.isin sorts).
        held = np.zeros(store.size, bool)
        held[cur.points.rows[cur.points.rows >= 0]] = True
        cand = self.local_rows[~held[self.local_rows] & ~store.bad[self.local_rows]]
        if len(cand):
            assert cur.T_cw is not None
            pos = store.pos[cand]
            uv, z = project(cur.T_cw, pos, self.camera.fx, self.camera.fy, self.camera.cx, self.camera.cy)
            center = invert(cur.T_cw)[:3, 3]
            ray = pos - center
            dist = np.linalg.norm(ray, axis=1)
            max_d, min_d = store.max_dist[cand], store.min_dist[cand]
            view_cos = np.einsum("ij,ij->i", ray, store.normal[cand]) / np.maximum(dist, 1e-9)
            ok = self._inside(uv, z) & (dist >= 0.8 * min_d) & (dist <= 1.2 * max_d) & (view_cos >= 0.5)
            sel = np.nonzero(ok)[0]
            store.n_visible[cand[sel]] += 1
            if len(sel):
                level = self.pyr.predict_level(max_d[sel], dist[sel])
                th = 5.0 if cur.index < self.last_reloc_frame + 2 else 3.0  # RGB-D: 3 (ORB-SLAM2)
                # ORB-SLAM also widens the radius for points seen at a grazing angle (cos < 0.998).
                radius = th * np.where(view_cos[sel] > 0.998, 2.5, 4.0) * self.pyr.scales[level]
                qi, ti = self._search(cur, uv[sel], radius, level - 1, level, store.descriptor[cand[sel]])
                cur.points.put(ti, store.points(cand[sel[qi]]), cand[sel[qi]])
        self._optimize(cur)
        rows = cur.points.rows
        inlier_rows = rows[(rows >= 0) & ~cur.outlier]
        np.add.at(store.n_found, inlier_rows, 1)
        n_found = int((store.n_kf_obs[inlier_rows] > 0).sum())
        self.n_matches_inliers = n_found
        if cur.index < self.last_reloc_frame + self.cfg.max_frames and n_found < 50:
            return False
        return n_found >= 30

    # ------------------------------------------------------------------ keyframes
    def _need_new_keyframe(self, cur: FrameState) -> bool:
        """ORB-SLAM2 Tracking::NeedNewKeyFrame for RGB-D."""
        n_kfs = len(self.map.keyframes)
        if cur.index < self.last_reloc_frame + self.cfg.max_frames and n_kfs > self.cfg.max_frames:
            return False
        if self.ref_kf is None:
            return True
        min_obs = 3 if n_kfs > 2 else 2
        ref_matches = self.ref_kf.tracked_points(min_obs)
        idle = self.keyframes.idle()
        close = (cur.depth > 0) & (cur.depth < self.th_depth_m)
        tracked = (cur.points.rows >= 0) & ~cur.outlier
        n_tracked_close = int((close & tracked).sum())
        n_untracked_close = int((close & ~tracked).sum())
        need_close = n_tracked_close < 100 and n_untracked_close > 70
        th_ref = 0.4 if n_kfs < 2 else 0.75
        inl = self.n_matches_inliers
        c1a = cur.index >= self.last_kf_frame + self.cfg.max_frames
        c1b = cur.index >= self.last_kf_frame + self.cfg.min_frames and idle
        c1c = inl < ref_matches * 0.25 or need_close
        c2 = (inl < ref_matches * th_ref or need_close) and inl > 15
        if (c1a or c1b or c1c) and c2:
            queued = self.keyframes.queue_size()
            return idle or queued < 3 or (c1c and queued < self.cfg.max_queued_keyframes_when_weak)
        return False

    def _create_keyframe(self, cur: FrameState) -> None:
        """New keyframe; close keypoints without a point get one from depth (ORB-SLAM2 RGB-D)."""
        kf = self._make_keyframe(cur)
        idx = np.nonzero(cur.depth > 0)[0]
        idx = idx[np.argsort(cur.depth[idx], kind="stable")]
        # Closest first; stop after the first far keypoint once 100 were considered (ORB-SLAM2).
        far = np.flatnonzero((cur.depth[idx] > self.th_depth_m) & (np.arange(len(idx)) >= 100))
        if len(far):
            idx = idx[:far[0] + 1]
        new_idx = idx[cur.free_mask(self.map.store)[idx]]
        if len(new_idx):
            arr = np.asarray(new_idx, np.intp)
            for i in arr.tolist():
                kf.points[i] = None
            self._new_points_from_keyframe(kf, cur, arr, cur.world_points(arr, self.camera))
        self.map.add_keyframe(kf)
        self.ref_kf = kf
        cur.ref_kf = kf
        self.last_kf_frame = cur.index
        self.keyframes.insert(kf)

    # ------------------------------------------------------------------ relocalisation
    def _relocalise(self, cur: FrameState) -> bool:
        """Bag-of-words candidates, PnP-RANSAC, pose optimisation, guided search (>= 50 inliers).
        Off without a vocabulary that tells places apart (float descriptors): stays lost."""
        from semslam.place.database import detect_relocalisation_candidates

        if not self.voc.recognises_places:
            return False

        self._compute_bow(cur)
        def covisibles(kf_id: int, n: int) -> list[int]:
            other = self.map.keyframes.get(kf_id)
            return [] if other is None else [c.id for c in other.best_covisibles(n)]

        candidates = detect_relocalisation_candidates(self.db, cur.bow, covisibles)
        # The active map first, then the others (ORB-SLAM3 tries the active map only; here a
        # relocalisation into another map leaves loop closing a merge hint, Atlas.activate).
        active = self.map.active_map
        candidates.sort(key=lambda i: i not in self.map.keyframes or self.map.keyframes[i].map_id != active)
        for kf_id in candidates:
            kf = self.map.keyframes.get(kf_id)
            if kf is None or kf.bad:
                continue
            kf_valid = np.array([p is not None and not p.bad for p in kf.points], bool)
            ia, ib = search_by_bow(kf.featvec, kf.keypoints.descriptors, cur.featvec or {}, cur.keypoints.descriptors,
                                   kf_valid, np.ones(len(cur), bool), self.map.matcher,
                                   self.spec.th_low, ratio=0.75)
            if len(ia) < 15:
                continue
            pts = np.array([kf.points[a].pos for a in ia])  # type: ignore[union-attr]
            cv2.setRNGSeed(self.seed)
            ok, rvec, tvec, inl = cv2.solvePnPRansac(pts.reshape(-1, 1, 3), cur.xy[ib].reshape(-1, 1, 2), self.camera.K, None,
                                                     iterationsCount=300, reprojectionError=5.991 ** 0.5 * 2,
                                                     confidence=0.99, flags=cv2.SOLVEPNP_AP3P)
            if not ok or inl is None or len(inl) < 10:
                continue
            rot, _ = cv2.Rodrigues(rvec)
            T = np.eye(4)
            T[:3, :3], T[:3, 3] = rot, tvec.reshape(3)
            cur.T_cw = T
            cur.clear_points()
            for k in inl.reshape(-1):
                cur.points[ib[k]] = kf.points[ia[k]]
            n_good = self._optimize(cur)
            if n_good < 10:
                continue
            self._discard_outliers(cur)
            if n_good < 50:
                # Guided search with the candidate's points to gather more matches.
                self._project_keyframe_points(cur, kf, 10.0)
                n_good = self._optimize(cur)
                self._discard_outliers(cur)
            if n_good >= 50:
                self.ref_kf = kf
                cur.ref_kf = kf
                if self.atlas is not None and kf.map_id != self.map.active_map:
                    self.atlas.activate(kf, self._bridge_to(cur))  # tracking goes on in that map
                return True
        cur.clear_points()
        cur.T_cw = None
        return False

    def _project_keyframe_points(self, cur: FrameState, kf: KeyFrame, th: float) -> int:
        have = {p.id for p in cur.points if p is not None}
        cand = [p for p in kf.valid_points() if p.id not in have]
        if not cand or cur.T_cw is None:
            return 0
        pos = np.array([p.pos for p in cand])
        uv, z = project(cur.T_cw, pos, self.camera.fx, self.camera.fy, self.camera.cx, self.camera.cy)
        dist = np.linalg.norm(pos - invert(cur.T_cw)[:3, 3], axis=1)
        max_d = np.array([p.max_dist for p in cand])
        ok = self._inside(uv, z)
        sel = np.nonzero(ok)[0]
        if len(sel) == 0:
            return 0
        level = self.pyr.predict_level(max_d[sel], dist[sel])
        qi, ti = self._search(cur, uv[sel], th * self.pyr.scales[level], level - 1, level + 1,
                              np.stack([cand[s].descriptor for s in sel]))
        for q, t in zip(qi, ti):
            cur.points[t] = cand[sel[q]]
        return len(qi)
