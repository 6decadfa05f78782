"""ORB-SLAM2 tracking for RGB-D: motion model or reference keyframe, then the local map,
pose-only optimisation after each matching step, keyframe decision, relocalisation.

The thresholds are ORB-SLAM2's (Tracking.cc); where this code simplifies, a comment says so.
What predicts or corrects a pose besides the features (the constant velocity, blur
coasting, depth odometry, a rolling shutter) are pose priors (``slam/orb/motion_priors/``),
asked at fixed points of the flow; the sensor's frames become ``FrameState`` through a
frame builder (``slam/orb/frame_builders.py``); the atlas's side is ``atlas.AtlasFollower``.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from contextlib import AbstractContextManager, nullcontext
from dataclasses import replace
from typing import TYPE_CHECKING, Any

import cv2
import numpy as np
from numpy.typing import NDArray

from semslam.backend.pose_only import optimize_pose
from semslam.config import SystemConfig
from semslam.core.imu import ImuCalibration
from semslam.core.protocols import DepthSource, DynamicStage, Extractor, FramePacket, MotionPrior
from semslam.core.types import ScalePyramid, TrackingState, TrackResult
from semslam.dynamics.masks import keypoints_in_mask
from semslam.dynamics.multiview import reference_views
from semslam.dynamics.multiview_mono import mono_views
from semslam.geometry.camera import PinholeCamera
from semslam.geometry.se3 import invert, orthonormalize
from semslam.slam.orb.atlas import AtlasFollower
from semslam.slam.orb.depth_prior import DepthPrior
from semslam.slam.orb.frame_builders import FrameBuilder, MonocularFrameBuilder, StereoFrameBuilder, frame_builder
from semslam.slam.orb.frame_state import FrameState
from semslam.slam.orb.inertial_links import MotionChain
from semslam.slam.orb.keyframe_worker import KeyframeSink
from semslam.slam.orb.map import KeyFrame, Map, update_normals_and_depths
from semslam.slam.orb.map_alignment import align_map, aligned_pose, rescale_frame_records, scaled_translation
from semslam.slam.orb.mono_init import MonocularInitializer
from semslam.slam.orb.motion_priors.base import FrameImages, FrameOutcome, MotionState, PosePrior, PosePrediction, Stage
from semslam.slam.orb.motion_priors.blur_coast import BlurCoast
from semslam.slam.orb.motion_priors.constant_velocity import ConstantVelocity
from semslam.slam.orb.motion_priors.depth_odometry import DepthOdometry
from semslam.slam.orb.motion_priors.inertial import InertialPrior
from semslam.slam.orb.motion_priors.rolling_shutter import RollingShutter
from semslam.slam.orb.motion_priors.sharpness_history import SharpnessHistory
from semslam.slam.orb.row_kernels import first_seen_unique
from semslam.geometry.projection import project
from semslam.slam.orb.search import rotation_consistent, search_by_bow, search_by_projection

if TYPE_CHECKING:
    from semslam.place.database import KeyframeDatabase
    from semslam.slam.orb.atlas import Atlas
    from semslam.place.vocabulary import Vocabulary


def pose_priors(config: SystemConfig, camera: PinholeCamera, slam_map: Map, pyramid: ScalePyramid,
                sharpness: SharpnessHistory, imu: ImuCalibration | None = None,
                align_map: Callable[[NDArray[np.float64], float], None] | None = None,
                monocular: bool = False) -> list[PosePrior]:
    """The priors ``config`` turns on, in the order tracking asks them: the rolling shutter
    (keypoints moved before anything; by the IMU's measured motion when there is one), the
    images' shift on blurred frames (its prediction before the others'; its coast before depth
    odometry), depth odometry, the IMU (its prediction wherever the blurred frames' shift has
    none; it poses a frame only when nothing before it could: ahead of the coast it posed
    blurred turns itself, and their coasted poses are better), and the constant velocity last
    (the motion model's fallback)."""
    cfg = config.slam
    inertial = (InertialPrior(config.imu, imu, align_map, monocular, keyframe_min_depth_points=cfg.min_init_keypoints // 2)
                if imu is not None else None)
    priors: list[PosePrior] = []
    if cfg.rolling_shutter_ms > 0:
        priors.append(RollingShutter(cfg, camera, slam_map, pyramid,
                                     inertial.camera_motion if inertial is not None else None))
    if cfg.blur_coast_sharp_ratio > 0:
        priors.append(BlurCoast(cfg, camera, slam_map, pyramid, sharpness))
    if cfg.depth_odometry != "none":
        priors.append(DepthOdometry(cfg, camera, sharpness))
    if inertial is not None:
        priors.append(inertial)
    priors.append(ConstantVelocity())
    return priors


class Tracking:
    """Owns the current frame and decides when to make keyframes; see the module docstring."""

    def __init__(self, config: SystemConfig, camera: PinholeCamera, slam_map: Map, vocabulary: "Vocabulary",
                 database: "KeyframeDatabase", extractor: Extractor, keyframes: KeyframeSink,
                 depth: DepthSource, dynamics: DynamicStage | None, atlas: "Atlas | None" = None,
                 builder: FrameBuilder | None = None, priors: list[PosePrior] | None = None,
                 depth_prior: DepthPrior | None = None, imu: ImuCalibration | None = None) -> None:
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
        self.builder = builder if builder is not None else frame_builder(config, camera)
        # Monocular (no depth at all): two-view initialisation and ORB-SLAM's monocular
        # thresholds where they differ from RGB-D's.
        self.mono = isinstance(self.builder, MonocularFrameBuilder)
        self.stereo = isinstance(self.builder, StereoFrameBuilder)
        self.mono_init = (MonocularInitializer(camera, slam_map.matcher, self.spec.th_low, config.seed,
                                               inv_sigma2=self.pyr.inv_sigma2)
                          if self.mono else None)
        self.depth_prior = depth_prior  # a depth network's, checked: scales the initial map
        self.sharpness = SharpnessHistory()
        self.priors = (priors if priors is not None
                       else pose_priors(config, camera, slam_map, self.pyr, self.sharpness, imu,
                                        self.align_map, self.mono))
        self.seed = config.seed
        self.th_depth_m = self.cfg.bf * self.cfg.th_depth / camera.fx
        self.state = TrackingState.NOT_INITIALIZED
        self.last: FrameState | None = None
        # The motion model: this frame's T_cw = velocity @ the last frame's, measured over
        # velocity_dt seconds (None: unknown).
        self.velocity: NDArray[np.float64] | None = None
        self.velocity_dt = 0.0
        self.ref_kf: KeyFrame | None = None
        self.last_kf_frame = -1
        self.last_kf_time = -np.inf
        # With an IMU, a keyframe at least this often (ORB-SLAM3's temporal condition; 0: none).
        self.keyframe_every_s = config.imu.keyframe_every_s if imu is not None else 0.0
        self.last_reloc_frame = -(10**9)
        self.local_kfs: list[KeyFrame] = []
        self.local_rows = np.zeros(0, np.intp)  # store rows of the local map's points
        self.n_relocalisations = 0
        self.n_matches_inliers = 0
        self.n_culled_dynamic_points = 0
        self._dropped: NDArray[np.bool_] | None = None  # keypoints removed as moving, this frame
        # This frame's pose prior for the pose optimisation: (timestamp, T_cw, information),
        # from a prediction that came with a covariance (the IMU's).
        self._pose_prior: tuple[float, NDArray[np.float64], NDArray[np.float64]] | None = None
        # With an IMU: its motion since the last keyframe, each new keyframe linked by it for
        # local BA; and this frame's measured motion from the last, (timestamp, motion, covariance).
        self.motion_chain = MotionChain() if imu is not None and config.imu.keyframe_links else None
        self._frame_motion: tuple[float, NDArray[np.float64], NDArray[np.float64]] | None = None
        self.last_dynamic_ratio = 0.0
        # Per tracked frame: (timestamp, reference keyframe, T_c_ref) for the trajectory.
        # Lost frames have no pose and are not recorded (ORB-SLAM's SaveTrajectoryTUM skips them).
        self.trajectory_refs: list[tuple[float, KeyFrame, NDArray[np.float64]]] = []
        # Multi-map atlas (ORB-SLAM3): a new map is wanted once lost long enough.
        self.atlas_follower = AtlasFollower(atlas) if atlas is not None else None
        self.new_map_pending = False
        # The IMU's estimation moves the map (gravity down its z axis; a monocular map to
        # metres) during a frame: (rotation, scale), applied after the frame's critical
        # section, with local mapping paused by this context (the assembler's; nothing to
        # pause when local mapping runs inline).
        self._pending_alignment: tuple[NDArray[np.float64], float] | None = None
        self.pause_mapping: Callable[[], AbstractContextManager[object]] = nullcontext

    # ------------------------------------------------------------------ the priors' counters
    def prior_counters(self) -> dict[str, Any]:
        """Every prior's counters, by their ``stats.json`` names (0 for a prior that is off)."""
        counters = dict.fromkeys(("depth_odometry_frames", "coasted_frames", "coast_keyframes",
                                  "coasted_on_shift_only", "depth_odometry_runs"), 0)
        for prior in self.priors:
            counters.update(prior.counters())
        if self.motion_chain is not None:
            counters["imu_keyframe_links"] = self.motion_chain.n_links
        return counters

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
        self.sharpness.begin(packet.sharpness)  # measured ahead by the reader, or None
        timings: dict[str, float] = {}
        dynamic, mask = None, None
        if self.dynamics is not None:
            dynamic, mask, wait_ms = self.dynamics.before_extraction(packet, self._motion_prior())
            if dynamic is not None:
                timings["semantic_wait"] = wait_ms
        t0 = time.perf_counter()
        self._dropped = None  # set by _remove_moving
        self.builder.begin(frame, mask)  # a stereo pair's right image, extracted beside the left
        kps = self.extractor.extract(frame.gray, mask)
        depth = self.depth.depth(frame)
        images = FrameImages(frame, depth)
        cur = self.builder.build(frame.index, frame.timestamp, kps, depth)
        self._correct(Stage.FEATURES, cur, True, images, timings)
        timings["extract"] = (time.perf_counter() - t0) * 1e3
        is_kf = False
        posed_by: PosePrior | None = None
        centre: NDArray[np.float64] | None = None
        t_wait = time.perf_counter()
        with self.map.lock:
            t0 = time.perf_counter()
            timings["lock_wait"] = (t0 - t_wait) * 1e3
            self._follow_atlas(frame.timestamp)
            started_map = self.state is TrackingState.NOT_INITIALIZED or self.new_map_pending
            if started_map:
                ok = self._initialize(cur)
                is_kf = ok
                timings["track"] = (time.perf_counter() - t0) * 1e3
                if not ok:
                    return TrackResult(frame.timestamp, None, self.state, n_keypoints=len(kps), timings=timings,
                                       dynamic=dynamic, keypoints_xy=kps.xy)
            else:
                ok, posed_by = self._track_in_map(cur, images, timings)
                if ok and self.dyn.multiview and self.dynamics is not None and (depth is not None or self.mono):
                    dynamic = self._check_moving(cur, depth, dynamic, posed_by, timings)
                self.state = TrackingState.OK if ok else TrackingState.LOST
                if ok:
                    assert cur.T_cw is not None
                    centre = invert(cur.T_cw)[:3, 3]  # as tracked, before a merge moves the world
                    is_kf = self._tracked(cur, posed_by, timings)
                else:
                    self.velocity = None
                    if cur.T_cw is None:
                        cur.T_cw = self.last.T_cw.copy() if self.last is not None and self.last.T_cw is not None else np.eye(4)
            if cur.ref_kf is None:
                cur.ref_kf = self.ref_kf
            if self.atlas_follower is not None:
                self.atlas_follower.apply_world_change(cur)  # a merge inside this frame's keyframe (sequential)
            recorded_at = self._record(cur) if self.state is TrackingState.OK else None
            self.last = cur
            outcome = FrameOutcome(cur, images, self.state is TrackingState.OK, started_map, posed_by, is_kf,
                                   self.velocity, centre, self.n_matches_inliers, self.trajectory_refs, recorded_at)
            for prior in self.priors:
                prior.update(outcome)
            self.sharpness.end(self.state is TrackingState.OK)
            n_inl = int(((cur.points.rows >= 0) & ~cur.outlier).sum())
        if self._pending_alignment is not None:
            t0 = time.perf_counter()
            self._apply_map_alignment()
            timings["align_map"] = (time.perf_counter() - t0) * 1e3
        pose_wc = invert(cur.T_cw) if cur.T_cw is not None and self.state is TrackingState.OK else None
        # count_nonzero: the same value as mean() of the bool mask without its float copy (0.3 ms)
        self.last_dynamic_ratio = np.count_nonzero(dynamic) / dynamic.size if dynamic is not None else 0.0
        static = ~self._dropped if self._dropped is not None else np.ones(len(kps), bool)
        return TrackResult(frame.timestamp, pose_wc, self.state, n_matches=n_inl, n_inliers=n_inl,
                           n_keypoints=len(kps), is_keyframe=is_kf, dynamic_ratio=self.last_dynamic_ratio,
                           timings=timings, dynamic=dynamic, keypoints_xy=kps.xy, keypoint_static=static,
                           posed_by=posed_by.name if posed_by is not None and pose_wc is not None else "")

    def _motion_state(self) -> MotionState:
        return MotionState(self.last, self.state is TrackingState.OK, self.velocity, self.velocity_dt)

    def _track_in_map(self, cur: FrameState, images: FrameImages,
                      timings: dict[str, float]) -> tuple[bool, PosePrior | None]:
        """Motion model or reference keyframe (relocalisation when lost), then the local map,
        each step followed by the priors' corrections. ``(tracked, the prior that posed the
        frame or None)``."""
        t0 = time.perf_counter()
        state = self._motion_state()
        # Every prior is asked (a prior may measure something for its correction as it
        # predicts: the blurred frames' image shift); the first prediction wins.
        predictions = [prior.predict(state, images) for prior in self.priors]
        prediction = next((p for p in predictions if p is not None), None)
        # The search starts from the first prediction; the pose is held near the first one
        # that knows its spread (the IMU's, also where the blurred frames' shift is the start).
        held = next((p for p in predictions if p is not None and p.covariance is not None), None)
        self._pose_prior = (None if held is None else
                            (cur.timestamp, held.T_cw, np.linalg.inv(held.covariance)))
        if self.motion_chain is not None:
            measured = next((p for p in predictions if p is not None and p.motion_covariance is not None), None)
            last = self.last
            self._frame_motion = (None if measured is None or last is None or last.T_cw is None else
                                  (cur.timestamp, measured.T_cw @ invert(last.T_cw), measured.motion_covariance))
        ok = self._track_frame(cur, prediction, timings)
        ok, _ = self._correct(Stage.MATCHED, cur, ok, images, timings)
        timings["track"] = (time.perf_counter() - t0) * 1e3
        if ok:
            t0 = time.perf_counter()
            ok = self.track_local_map(cur)
            timings["local_map"] = (time.perf_counter() - t0) * 1e3
        return self._correct(Stage.LOCAL_MAP, cur, ok, images, timings)

    def _correct(self, stage: Stage, cur: FrameState, ok: bool, images: FrameImages,
                 timings: dict[str, float]) -> tuple[bool, PosePrior | None]:
        """The priors' corrections at ``stage``, in order, until one poses the frame."""
        state = self._motion_state()
        for prior in self.priors:
            t0 = time.perf_counter()
            correction = prior.correct(stage, state, cur, ok, images, self)
            if correction is None:
                continue
            timings[prior.name] = (time.perf_counter() - t0) * 1e3
            ok = correction.tracked
            if correction.posed:
                return ok, prior
        return ok, None

    def _tracked(self, cur: FrameState, posed_by: PosePrior | None, timings: dict[str, float]) -> bool:
        """A tracked frame: the motion model's velocity, the keyframe decision, the outliers
        dropped. True when it made a keyframe."""
        assert cur.T_cw is not None
        last = self.last
        if self.motion_chain is not None:
            motion = self._frame_motion
            self.motion_chain.frame(*((motion[1], motion[2]) if motion is not None and motion[0] == cur.timestamp
                                      else (None, None)))
        self.velocity = cur.T_cw @ invert(last.T_cw) if last is not None and last.T_cw is not None else None
        self.velocity_dt = cur.timestamp - last.timestamp if last is not None else 0.0
        if self.atlas_follower is not None:
            self.atlas_follower.tracked(cur.timestamp, cur.T_cw.copy(), self.velocity, self.velocity_dt)
        is_kf = False
        if not self.cfg.localization_only and self._keyframe_wanted(cur, posed_by):
            t0 = time.perf_counter()
            self._create_keyframe(cur)
            timings["keyframe"] = (time.perf_counter() - t0) * 1e3
            is_kf = True
        # Outliers are not carried to the next frame (ORB-SLAM discards them here).
        out = np.flatnonzero(cur.outlier)
        cur.points.put(out, [None] * out.size, np.full(out.size, -1, np.intp))
        cur.outlier[:] = False
        return is_kf

    def _keyframe_wanted(self, cur: FrameState, posed_by: PosePrior | None) -> bool:
        """ORB-SLAM2's decision, or for a frame a prior posed, that prior's."""
        if posed_by is None:
            return self._need_new_keyframe(cur, self.mono)
        return posed_by.keyframe_wanted(self._motion_state(), cur, self, lambda: self._need_new_keyframe(cur, self.mono))

    # ------------------------------------------------------------------ dynamics
    def _motion_prior(self) -> MotionPrior | None:
        """The last frame's pose and the motion model, for a skipped frame's warped mask."""
        last = self.last
        if last is None or last.T_cw is None:
            return None
        velocity = self.velocity if self.state is TrackingState.OK else None
        return MotionPrior(last.index, last.T_cw, velocity)

    def _check_moving(self, cur: FrameState, depth: NDArray[np.float32] | None, dynamic: NDArray[np.bool_] | None,
                      posed_by: PosePrior | None, timings: dict[str, float]) -> NDArray[np.bool_] | None:
        """DDL-SLAM's multi-view check on a tracked frame (``_remove_moving``); a pose a prior
        gave the frame stays, since a refit on the few matches left would undo it."""
        t0 = time.perf_counter()
        T_posed = cur.T_cw.copy() if posed_by is not None and cur.T_cw is not None else None
        dynamic = self._remove_moving(cur, depth, dynamic)
        if T_posed is not None:
            cur.T_cw = T_posed
            self.keep_matches_consistent(cur)
        timings["multiview"] = (time.perf_counter() - t0) * 1e3
        return dynamic

    def _remove_moving(self, cur: FrameState, depth: NDArray[np.float32] | None,
                       dynamic: NDArray[np.bool_] | None) -> NDArray[np.bool_] | None:
        """With the pose just tracked, the dynamic stage finds moving regions (DDL-SLAM's
        multi-view geometry); keypoints there (and in their border band) are dropped, the map
        points matched inside are culled and the pose re-optimised."""
        ref = self.ref_kf
        if ref is None or cur.T_cw is None or self.dynamics is None:
            return dynamic
        if depth is None:  # monocular: the check's two-view form (dynamics/multiview_mono.py)
            view, views = mono_views(cur, ref, cur.timestamp, self.dyn.multiview_keyframes, self.dyn.multiview_min_age_s)
            regions = self.dynamics.after_pose_mono(view, views, self.spec)
        else:
            refs = reference_views(ref, cur.timestamp, self.dyn.multiview_keyframes, self.dyn.multiview_min_age_s)
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
            self.optimize(cur)
        return regions.moving if dynamic is None else (dynamic | regions.moving)

    def _record(self, cur: FrameState) -> int | None:
        """The frame in the trajectory, relative to its reference keyframe; its entry."""
        ref = cur.ref_kf or self.ref_kf
        if ref is None or cur.T_cw is None:
            return None
        self.trajectory_refs.append((cur.timestamp, ref, cur.T_cw @ ref.T_wc))
        return len(self.trajectory_refs) - 1

    def align_map(self, rotation: NDArray[np.float64], scale: float) -> None:
        """The map to be moved by ``x' = scale * rotation @ x`` (the IMU's gravity and, for a
        monocular map, its scale): applied once the frame's critical section ends
        (``_apply_map_alignment``), composed with one already pending."""
        if self._pending_alignment is not None:
            R0, s0 = self._pending_alignment
            rotation, scale = rotation @ R0, scale * s0
        self._pending_alignment = (np.asarray(rotation, dtype=np.float64), float(scale))

    def _apply_map_alignment(self) -> None:
        """The pending alignment, with local mapping paused (a keyframe it has in hand was
        triangulated in the old frame) and under the map lock: the active map, the frames
        recorded relative to its keyframes, the last frame, the motion model and the priors'
        positions."""
        pending, self._pending_alignment = self._pending_alignment, None
        if pending is None or self.ref_kf is None:
            return
        with self.pause_mapping(), self.map.lock:
            self._align_state(self.ref_kf.map_id, *pending)

    def _align_state(self, map_id: int, rotation: NDArray[np.float64], scale: float) -> None:
        kfs = align_map(self.map, map_id, rotation, scale)
        rescale_frame_records(self.trajectory_refs, dict.fromkeys(kfs, scale))
        if self.last is not None and self.last.T_cw is not None:
            self.last.T_cw = aligned_pose(self.last.T_cw, rotation, scale)
        if self.velocity is not None:  # camera to camera: only its translation's units change
            self.velocity = scaled_translation(self.velocity, scale)
        follower = self.atlas_follower
        if follower is not None and follower.last_tracked is not None and follower.last_tracked.map_id == map_id:
            last = follower.last_tracked
            follower.last_tracked = replace(last, T_cw=aligned_pose(last.T_cw, rotation, scale),
                                            velocity=None if last.velocity is None
                                            else scaled_translation(last.velocity, scale))
        if self.depth_prior is not None and scale != 1.0:
            self.depth_prior.map_scaled(scale)
        for prior in self.priors:
            prior.map_aligned(rotation, scale)

    # ------------------------------------------------------------------ atlas
    def _follow_atlas(self, timestamp: float) -> None:
        """Under the map lock before a frame: the last frame into its map's new world after
        a merge; a new map once lost long enough, which the next frame starts."""
        if self.atlas_follower is None:
            return
        if self.atlas_follower.new_map_wanted(self.last, self.state is TrackingState.LOST, self.new_map_pending, timestamp):
            self.new_map_pending = True
            self.velocity = None
            self.local_kfs = []
            self.local_rows = np.zeros(0, np.intp)

    # ------------------------------------------------------------------ initialisation
    def _initialize(self, cur: FrameState) -> bool:
        """First frame with enough keypoints becomes keyframe 0 at the origin, points from depth
        (monocular: two views, ``_initialize_monocular``)."""
        if self.mono_init is not None:
            return self._initialize_monocular(cur)
        if len(cur) < self.cfg.min_init_keypoints or (cur.depth > 0).sum() < self.cfg.min_init_keypoints // 2:
            return False
        cur.T_cw = np.eye(4)
        kf = self._make_keyframe(cur)
        idx = np.nonzero(cur.depth > 0)[0]
        self._new_points_from_keyframe(kf, cur, idx, cur.world_points(idx, self.camera))
        self.map.add_keyframe(kf)
        self.keyframes.insert(kf)
        self._map_started(cur, [kf])
        return True

    def _initialize_monocular(self, cur: FrameState) -> bool:
        """ORB-SLAM's MonocularInitialization / CreateInitialMapMonocular: once a pair holds,
        the reference becomes keyframe 0 at the origin and this frame keyframe 1, with the
        triangulated points (median depth 1) seen by both."""
        assert self.mono_init is not None
        pair = self.mono_init.attempt(cur)
        if pair is None:
            return False
        self.mono_init.reset()
        ref = pair.reference
        ref.clear_points()
        cur.clear_points()
        points_w, T_21 = pair.points_w, pair.T_cw.copy()
        if self.depth_prior is not None and ref.prior_depth is not None:
            # Metric when the depth network agrees with the two views (the reference is the
            # origin: a point's depth there is its z).
            scale = self.depth_prior.initial_map_scale(points_w[:, 2], ref.prior_depth[pair.idx_ref])
            if scale is not None:
                points_w, T_21[:3, 3] = points_w * scale, T_21[:3, 3] * scale
        ref.T_cw = np.eye(4)
        cur.T_cw = T_21
        kf0, kf1 = self._make_keyframe(ref), self._make_keyframe(cur)
        made = []
        for a, b, pw in zip(pair.idx_ref.tolist(), pair.idx_cur.tolist(), points_w):
            p = self.map.new_point(pw, kf0.keypoints.descriptors[a], kf0)
            p.add_observation(kf0, a)
            p.add_observation(kf1, b)
            kf0.points[a] = p
            kf1.points[b] = p
            cur.points[b] = p
            made.append(p)
        update_normals_and_depths(made, self.pyr.scales)
        for kf in (kf0, kf1):
            self.map.add_keyframe(kf)
        for kf in (kf0, kf1):
            kf.update_connections()
        for kf in (kf0, kf1):
            self.keyframes.insert(kf)
        self.velocity = None  # ORB-SLAM: the next frame tracks the reference keyframe
        self._map_started(cur, [kf0, kf1])
        return True

    def _map_started(self, cur: FrameState, keyframes: list[KeyFrame]) -> None:
        """A map starts with ``keyframes``, the last one this frame's: it is the reference and
        they are the local map."""
        kf = keyframes[-1]
        if self.motion_chain is not None:
            self.motion_chain.lost()  # the IMU state starts over with the map
            self.motion_chain.new_keyframe(kf)
        self.ref_kf = kf
        cur.ref_kf = kf
        self.last_kf_frame, self.last_kf_time = cur.index, cur.timestamp
        self.local_kfs = keyframes
        self.local_rows = kf.points.rows[kf.points.rows >= 0]
        self.state = TrackingState.OK
        self.new_map_pending = False

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
                      cur.depth, cur.ur, list(cur.points), predicted_depth=cur.prior_depth)
        if cur.bow is not None:
            kf.bow, kf.featvec = cur.bow, cur.featvec or {}
        return kf

    # ------------------------------------------------------------------ frame tracking
    def _track_frame(self, cur: FrameState, prediction: PosePrediction | None, timings: dict[str, float]) -> bool:
        """Motion model from the priors' prediction, else the reference keyframe; when lost,
        relocalisation."""
        if self.state is TrackingState.OK:
            ok = False
            if self.velocity is not None and prediction is not None and cur.index > self.last_reloc_frame + 1:
                ok = self._track_with_motion_model(cur, prediction)
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

    def optimize(self, cur: FrameState) -> int:
        """Pose-only optimisation over the frame's matched points (held near this frame's
        predicted pose when the prediction came with a covariance); marks outliers."""
        idx = cur.matched_indices(self.map.store)
        if len(idx) < 3:
            return 0
        assert cur.T_cw is not None
        pts = self.map.store.pos[cur.points.rows[idx]]
        oct_ = cur.keypoints.octave[idx]
        held = self._pose_prior
        prior = held[1:] if held is not None and held[0] == cur.timestamp else None
        res = optimize_pose(cur.T_cw, pts, cur.xy[idx], cur.ur[idx], self.pyr.inv_sigma2[oct_],
                            self.camera.fx, self.camera.fy, self.camera.cx, self.camera.cy, self.cfg.bf,
                            prior=prior)
        cur.T_cw = orthonormalize(res.T_cw)
        cur.outlier[:] = False
        cur.outlier[idx[~res.inliers]] = True
        return int(res.inliers.sum())

    def keep_matches_consistent(self, cur: FrameState, th_px: float = 5.991 ** 0.5) -> None:
        """Unmatch the keypoints whose map point projects farther than ``th_px`` (x the
        level's scale) from them under the frame's pose (a prior's pose, not fitted to them)."""
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

    def discard_outliers(self, cur: FrameState) -> int:
        """Unmatch the outliers; the number of matches left whose point is in a keyframe."""
        for i in np.flatnonzero(cur.outlier & (cur.points.rows >= 0)).tolist():
            cur.points[i] = None
        cur.outlier[:] = False
        rows = cur.points.rows
        rows = rows[rows >= 0]
        return int((self.map.store.n_kf_obs[rows] > 0).sum())

    def _track_with_motion_model(self, cur: FrameState, prediction: PosePrediction) -> bool:
        last = self.last
        assert last is not None and last.T_cw is not None
        cur.T_cw = prediction.T_cw
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
        forward = t_lc[2] > self.cfg.bf / self.camera.fx and not self.mono
        backward = -t_lc[2] > self.cfg.bf / self.camera.fx and not self.mono
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
        self.optimize(cur)
        return self.discard_outliers(cur) >= 10

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
        self.optimize(cur)
        return self.discard_outliers(cur) >= 10

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

    def track_local_map(self, cur: FrameState) -> bool:
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
                # RGB-D: 3, monocular: 1 (ORB-SLAM2 SearchLocalPoints)
                th = 5.0 if cur.index < self.last_reloc_frame + 2 else (1.0 if self.mono else 3.0)
                # ORB-SLAM also widens the radius for points seen at a grazing angle (cos < 0.998).
                radius = th * np.where(view_cos[sel] > 0.998, 2.5, 4.0) * self.pyr.scales[level]
                qi, ti = self._search(cur, uv[sel], radius, level - 1, level, store.descriptor[cand[sel]])
                cur.points.put(ti, store.points(cand[sel[qi]]), cand[sel[qi]])
        self.optimize(cur)
        rows = cur.points.rows
        inlier_rows = rows[(rows >= 0) & ~cur.outlier]
        np.add.at(store.n_found, inlier_rows, 1)
        n_found = int((store.n_kf_obs[inlier_rows] > 0).sum())
        self.n_matches_inliers = n_found
        if cur.index < self.last_reloc_frame + self.cfg.max_frames and n_found < 50:
            return False
        return n_found >= 30

    # ------------------------------------------------------------------ keyframes
    def _need_new_keyframe(self, cur: FrameState, mono: bool = False) -> bool:
        """ORB-SLAM2 Tracking::NeedNewKeyFrame for RGB-D, or with ``mono`` for a monocular
        camera (no close points, a 0.9 reference ratio, no c1c, nothing inserted while local
        mapping is busy); with an IMU and ``imu.keyframe_every_s`` set, also ORB-SLAM3's
        temporal condition (c3: that long since the last keyframe), which alone suffices: a
        reference keyframe whose points no other keyframe sees (a new view after a turn) leaves
        ORB-SLAM2's reference count at zero, and its test never fires again."""
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
        # ORB-SLAM2 relaxes the ratio to 0.4 while the map has one keyframe. A stereo pair's
        # first keyframe holds only its stereo-matched keypoints, and its tracked share then
        # stays above 0.4 for hundreds of frames of a slow path (one keyframe in 200 frames
        # on the stereo renders); 0.75 throughout, as ORB-SLAM3 keeps for two-camera rigs.
        th_ref = 0.9 if mono else (0.4 if n_kfs < 2 and not self.stereo else 0.75)
        inl = self.n_matches_inliers
        c1a = cur.index >= self.last_kf_frame + self.cfg.max_frames
        c1b = cur.index >= self.last_kf_frame + self.cfg.min_frames and idle
        c1c = not mono and (inl < ref_matches * 0.25 or need_close)
        c2 = (inl < ref_matches * th_ref or need_close) and inl > 15
        c3 = self.keyframe_every_s > 0 and cur.timestamp - self.last_kf_time >= self.keyframe_every_s
        if ((c1a or c1b or c1c) and c2) or c3:
            if mono and not idle:
                return False
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
        if self.motion_chain is not None:
            self.motion_chain.new_keyframe(kf)
        self.map.add_keyframe(kf)
        self.ref_kf = kf
        cur.ref_kf = kf
        self.last_kf_frame, self.last_kf_time = cur.index, cur.timestamp
        self.keyframes.insert(kf)

    # ------------------------------------------------------------------ relocalisation
    def _relocalise(self, cur: FrameState) -> bool:
        """Bag-of-words candidates, PnP-RANSAC, pose optimisation, guided search (>= 50 inliers)
        (ORB-SLAM's Tracking::Relocalization; monocular as RGB-D, the map points being
        triangulated). Off without a vocabulary that tells places apart (float descriptors):
        stays lost."""
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
            # Monocular: EPnP, a non-minimal solver as ORB-SLAM3's MLPnP (Tracking::Relocalization);
            # AP3P and SQPnP relocalised on the same frames with the same poses (blackout and
            # jump_back renders). RGB-D keeps AP3P.
            pnp = cv2.SOLVEPNP_EPNP if self.mono else cv2.SOLVEPNP_AP3P
            cv2.setRNGSeed(self.seed)
            ok, rvec, tvec, inl = cv2.solvePnPRansac(pts.reshape(-1, 1, 3), cur.xy[ib].reshape(-1, 1, 2), self.camera.K, None,
                                                     iterationsCount=300, reprojectionError=5.991 ** 0.5 * 2,
                                                     confidence=0.99, flags=pnp)
            if not ok or inl is None or len(inl) < 10:
                continue
            rot, _ = cv2.Rodrigues(rvec)
            T = np.eye(4)
            T[:3, :3], T[:3, 3] = rot, tvec.reshape(3)
            cur.T_cw = T
            cur.clear_points()
            for k in inl.reshape(-1):
                cur.points[ib[k]] = kf.points[ia[k]]
            n_good = self.optimize(cur)
            if n_good < 10:
                continue
            self.discard_outliers(cur)
            if n_good < 50:
                # Guided search with the candidate's points to gather more matches.
                self._project_keyframe_points(cur, kf, 10.0)
                n_good = self.optimize(cur)
                self.discard_outliers(cur)
            if n_good >= 50:
                self.ref_kf = kf
                cur.ref_kf = kf
                if self.atlas_follower is not None:
                    self.atlas_follower.relocalised(kf, cur)  # in another map's keyframe: tracking goes on there
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
