"""SDF-SLAM's monocular tracker (000, IV): features on every frame, matches to a reference,
PnP-RANSAC on the reference's predicted depth (eqs. 9-10), keyframes, data correction.

Per frame: the dynamic stage's mask and labels (when on; the segmenter's labels go to the
semantic cloud), the extractor's keypoints, the depth source's depth map (a depth network:
SDFCNN; for tests the ``ground_truth_depth`` oracle), then the pose:

1. Reference: the last keyframe (``sdf_slam.reference: keyframe``) or the previous frame
   (``frame``, the paper's "two adjacent frames"); its keypoints with depth are 3D points in
   the world (a keyframe's: its feature tracks' positions, the local data correction: the
   median of their back-projections, or with ``min_parallax_deg`` the intersection of their
   rays where these spread enough).
2. Matching with the extractor's matcher: among keypoints within ``search_radius_px`` of
   where the constant-velocity model projects the reference's points, else by brute force,
   or with ``features.matcher: range`` by SDF-SLAM's range matcher (eq. 8: the nearest
   descriptor in a 140-px square around the keypoint, the paper's search, with no motion
   model), then again within 10 px of the pose found.
3. PnP-RANSAC + Levenberg-Marquardt (``sdf_slam_pnp``).
4. Recovery: when the reference fails, the other one (keyframe <-> previous frame) is
   tried, guided and unguided; when both fail the frame is lost (no pose; the constant-
   velocity prediction is kept to search from), and after ``reanchor_after`` lost frames in
   a row a frame with enough keypoints with depth becomes a new keyframe at that prediction (a weak edge in the pose graph, which
   sampled pairs can then correct) so tracking starts again from the current view.
5. Depth alignment (``sdf_slam.depth_alignment``, ours, not the paper's): a tracked frame's
   predicted depth is fitted to the map's depth of its PnP inliers (a scale, or a scale and a
   power in log depth) and its 3D points and depth map take the fitted depth, so the points it
   places keep the map's scale; the last fit serves frames without one.
6. Keyframe when the inliers fall below ``keyframe_min_inliers`` or the camera moved or
   turned past the thresholds: its features join the feature tracks (local correction), the
   result announces it with its predicted depth (the System feeds the map builders: the
   semantic cloud), and every ``global_every`` keyframes sampled keyframe pairs are solved
   and the keyframe poses corrected in a GTSAM pose graph (``sdf_slam_correction``); the
   result carries the corrected poses.

Frames are stored relative to their keyframe, so a corrected keyframe moves its frames
(ORB-SLAM's SaveTrajectoryTUM). Everything runs in the caller's thread; the pose graph is
tens of keyframes, milliseconds in GTSAM.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from semslam.backend.pose_graph import PoseGraphFailed
from semslam.config import SystemConfig
from semslam.config.checks import check_values
from semslam.core import registry
from semslam.core.protocols import FramePacket, MotionPrior, TrackerInputs
from semslam.core.types import Frame, KeyframeEvent, Keypoints, TrackingState, TrackResult
from semslam.errors import ConfigError, DataError
from semslam.features import create_extractor
from semslam.features.matching import matcher_for, pairs_within_radius
from semslam.geometry.camera import PinholeCamera
from semslam.geometry.se3 import invert
from semslam.core.trajectory import Trajectory
from semslam.slam.trackers.sdf_slam_correction import (DepthAlignment, Edge, TrackTable, ViewFeatures, candidate_pairs,
                                                       correct_poses, fit_depth_alignment, match_views, pair_constraint, relative_motion)
from semslam.frontend.keypoint_depth import sample_depth
from semslam.slam.trackers.sdf_slam_pnp import PnpSettings, solve_pnp

Array = NDArray[np.float64]

#: Radius (px) of the re-match around the projections of an unguided pose (ORB-SLAM: 10).
REFINE_RADIUS_PX = 10.0
#: Weight of the guessed edge to a re-anchored keyframe (a tracked edge weighs inliers / 100).
REANCHOR_WEIGHT = 1e-3


def create_tracker(config: SystemConfig, camera: PinholeCamera, inputs: TrackerInputs | None = None,
                   map_path: Path | None = None) -> "SdfSlamTracker":
    """The registry's factory: refuses what the tracker cannot do, with the key to change."""
    if inputs is None:
        raise ConfigError("tracking.method=sdf_slam needs the System's inputs (its depth source)")
    if map_path is not None:
        raise ConfigError("--load-map: the sdf_slam tracker keeps no saveable map (use --preset orb)")
    if config.dynamics.multiview:
        raise ConfigError("dynamics.multiview: not supported by tracking.method=sdf_slam (set it false)")
    if config.sensor == "stereo":
        raise ConfigError("sensor: stereo runs on tracking.method: orb_slam (its stereo matching); sdf_slam is "
                          "monocular (give --sensor mono to run it on the left images)")
    if config.sensor == "mono" and config.depth.source == "sensor":
        raise ConfigError("depth.source: a monocular sequence has no sensor depth; tracking.method=sdf_slam needs "
                          "a depth network (depth.source: sdfcnn) or, to test the tracker, ground_truth_depth")
    check_values(config.sdf_slam, "sdf_slam")
    return SdfSlamTracker(config, camera, inputs)


@dataclass
class _Reference:
    """What a frame is tracked against: keypoints with world points where they have depth."""

    features: ViewFeatures
    pts_w: Array
    kf_index: int  # -1 for the previous frame


@dataclass
class _PoseFit:
    """A frame's pose against a reference, with the inlier matches behind it."""

    T_wc: Array | None
    inliers: NDArray[np.bool_]
    n_matches: int
    query: NDArray[np.intp]  # frame keypoint of each match
    ref_pts_w: Array  # the reference's world point of each match


@dataclass
class _Keyframe:
    id: int
    timestamp: float
    T_wc: Array
    features: ViewFeatures
    tracks: NDArray[np.intp]  # per keypoint, -1 without depth


class SdfSlamTracker:
    """``core.protocols.Tracker`` for SDF-SLAM; see the module docstring."""

    has_map = False  # nothing to --save-map; map_points() are the feature tracks

    def __init__(self, config: SystemConfig, camera: PinholeCamera, inputs: TrackerInputs) -> None:
        self.cfg = config.sdf_slam
        self.camera = camera
        self.depth = inputs.depth
        self.dynamics = inputs.dynamics
        size = (camera.width, camera.height) if camera.width > 0 else None
        self.extractor = create_extractor(config.features, size)
        self.spec = self.extractor.spec
        self.matcher = matcher_for(self.spec)
        # features.matcher (the fpf branch adds the key): "range" is SDF-SLAM's eq. 8 window
        # matcher, used for the search without a pose; the guided searches stay the matcher's.
        self.range_matcher = (registry.create("matcher", "range")
                              if config.features.matcher == "range" else None)
        # With the range matcher the search is the paper's (no motion model); else guided first.
        self._searches = (False,) if self.range_matcher is not None else (True, False)
        self.max_distance = float(self.spec.th_high)
        c = self.cfg
        self.pnp = PnpSettings(c.ransac_reprojection_px, c.ransac_iterations, c.ransac_confidence, c.min_inliers,
                               config.seed)
        self.pair_pnp = PnpSettings(c.ransac_reprojection_px, c.ransac_iterations, c.ransac_confidence,
                                    c.global_min_inliers, config.seed)
        self.rng = np.random.default_rng(config.seed)
        self.keyframes: list[_Keyframe] = []
        self.tracks = TrackTable()
        self.edges: list[Edge] = []
        self._tried: set[tuple[int, int]] = set()
        self._frames: list[tuple[float, int, Array]] = []  # (timestamp, keyframe index, T_kf_c)
        self._kf_ref: _Reference | None = None
        self._last_ref: _Reference | None = None  # the previous frame, when it was tracked
        self._last_wc: Array | None = None  # tracked or predicted pose of the last frame
        self._last_index = -1
        self._delta: Array | None = None  # inv(T_wc(k-2)) @ T_wc(k-1): constant velocity
        self._n_lost = 0
        self._alignment = DepthAlignment()  # the last fit of predicted to map depth (depth_alignment)
        self._fits: list[tuple[float, float]] = []  # (power, median ratio) of every fit, for stats()
        self._min_points = max(2 * c.min_inliers, 50)  # keypoints with depth to start from (first, re-anchor)
        self._stopped = False
        self._announced: KeyframeEvent | None = None  # the keyframe this frame made
        self._corrected: dict[int, Array] | None = None  # keyframe poses this frame corrected
        self.counters = {"reanchors": 0, "fallback_reference": 0, "global_rounds": 0, "global_pairs_tried": 0,
                         "global_constraints": 0, "pose_graph_failed": 0, "alignment_kept": 0}

    # ------------------------------------------------------------------ per frame
    def prepare(self, frame: Frame) -> None:
        """Nothing runs ahead of tracking here."""

    def track(self, packet: FramePacket) -> TrackResult:
        frame = packet.frame
        timings: dict[str, float] = {}
        dynamic, mask = None, None
        if self.dynamics is not None:
            dynamic, mask, wait_ms = self.dynamics.before_extraction(packet, self._motion_prior())
            timings["wait_mask"] = wait_ms
        t0 = time.perf_counter()
        kps = self.extractor.extract(frame.gray, mask)
        timings["extract"] = (time.perf_counter() - t0) * 1e3
        self._announced, self._corrected = None, None
        t0 = time.perf_counter()
        depth = self.depth.depth(frame)
        timings["depth"] = (time.perf_counter() - t0) * 1e3
        if depth is None:
            raise DataError(frame.rgb_path or "frame", "the depth source gave no depth for this frame "
                                                       "(sdf_slam needs depth.source: a depth network)")
        if depth.shape != frame.rgb.shape[:2]:
            raise DataError(frame.rgb_path or "frame", f"the depth source gave {depth.shape[1]}x{depth.shape[0]} depth "
                                                       f"for a {frame.rgb.shape[1]}x{frame.rgb.shape[0]} image")
        view = self._view(kps, depth)
        if not self.keyframes:
            return self._initialise(packet, view, depth, kps, dynamic, timings)

        predicted = self._predict()
        fit = self._estimate(view, predicted, timings)
        T_wc, inl, n_matches = fit.T_wc, fit.inliers, fit.n_matches
        if self.cfg.depth_alignment != "none":
            view = self._align_depth(view, fit)
        state = TrackingState.OK if T_wc is not None else TrackingState.LOST
        is_kf = False
        if T_wc is not None:
            self._n_lost = 0
            self._advance(T_wc)
            self._last_index = frame.index
            self._last_ref = _Reference(view, self._to_world(view, T_wc), -1)
            if self._needs_keyframe(T_wc, int(inl.sum())):
                self._make_keyframe(packet, view, depth, T_wc, timings, weight=inl.sum() / 100.0)
                is_kf = True
        else:
            self._n_lost += 1
            self._last_ref = None
            assert predicted is not None
            self._last_wc, self._last_index = predicted, frame.index
            if self._n_lost >= self.cfg.reanchor_after and view.has_depth.sum() >= self._min_points:
                self.counters["reanchors"] += 1
                self._make_keyframe(packet, view, depth, predicted, timings, weight=REANCHOR_WEIGHT)
                self._n_lost, self._delta = 0, None
                is_kf = True
        if T_wc is not None:
            kf = self.keyframes[-1]
            self._frames.append((frame.timestamp, len(self.keyframes) - 1, invert(kf.T_wc) @ T_wc))
        return TrackResult(frame.timestamp, T_wc, state, n_matches=n_matches,
                           n_inliers=int(inl.sum()) if T_wc is not None else 0, n_keypoints=len(kps),
                           is_keyframe=is_kf, dynamic_ratio=float(dynamic.mean()) if dynamic is not None else 0.0,
                           timings=timings, dynamic=dynamic, keypoints_xy=kps.xy, keyframe=self._announced,
                           corrected_poses=self._corrected)

    def _align_depth(self, view: ViewFeatures, fit: _PoseFit) -> ViewFeatures:
        """The frame's 3D points with the predicted depth brought to the map's: fitted on its
        PnP inliers (``sdf_slam.depth_alignment``), else (a lost frame, too few inliers with
        depth, a fit out of bounds) by the last fit. The depth map follows at keyframes only
        (``_announce``): nothing else reads it."""
        z = view.pts_c[:, 2]
        fitted: NDArray[np.intp] | None = None  # the inliers' indices into the view, when this frame was fitted
        if fit.T_wc is not None:
            inliers = fit.query[fit.inliers]
            z_map = (fit.ref_pts_w[fit.inliers] - fit.T_wc[:3, 3]) @ fit.T_wc[:3, 2]
            found = fit_depth_alignment(z_map, z[inliers], self.cfg.depth_alignment, self.cfg.alignment_min_points)
            if found is not None:
                self._alignment, fitted = found, inliers
            else:
                self.counters["alignment_kept"] += 1
        factor = np.divide(self._alignment.apply(z), z, out=np.zeros_like(z), where=z > 0)
        if fitted is not None:  # stats(): the fit's power and its median map / predicted ratio
            self._fits.append((self._alignment.power, float(np.median(factor[fitted][z[fitted] > 0]))))
        return ViewFeatures(view.xy, view.descriptors, view.pts_c * factor[:, None], view.has_depth)

    def _view(self, kps: Keypoints, depth: NDArray[np.float32]) -> ViewFeatures:
        xy = self.camera.undistort_points(kps.xy)
        z = sample_depth(depth, kps.xy)
        has = np.isfinite(z) & (z > self.cfg.min_depth_m) & (z < self.cfg.max_depth_m)
        pts_c = self.camera.backproject(xy, np.where(has, z, 0.0))
        return ViewFeatures(xy, kps.descriptors, pts_c, has)

    @staticmethod
    def _to_world(view: ViewFeatures, T_wc: Array) -> Array:
        return view.pts_c @ T_wc[:3, :3].T + T_wc[:3, 3]

    def _initialise(self, packet: FramePacket, view: ViewFeatures, depth: NDArray[np.float32], kps: Keypoints,
                    dynamic: NDArray[np.bool_] | None, timings: dict[str, float]) -> TrackResult:
        frame = packet.frame
        if view.has_depth.sum() < self._min_points:
            return TrackResult(frame.timestamp, None, TrackingState.NOT_INITIALIZED, n_keypoints=len(kps),
                               timings=timings, dynamic=dynamic, keypoints_xy=kps.xy)
        pose = np.eye(4)
        self._make_keyframe(packet, view, depth, pose, timings, weight=0.0)
        self._advance(pose)
        self._last_index = frame.index
        self._last_ref = _Reference(view, self._to_world(view, pose), -1)
        self._frames.append((frame.timestamp, 0, np.eye(4)))
        return TrackResult(frame.timestamp, pose, TrackingState.OK, n_keypoints=len(kps), is_keyframe=True,
                           timings=timings, dynamic=dynamic, keypoints_xy=kps.xy, keyframe=self._announced,
                           corrected_poses=self._corrected)

    def _advance(self, T_wc: Array) -> None:
        if self._last_wc is not None:  # after lost frames: from the prediction it was searched from
            self._delta = invert(self._last_wc) @ T_wc
        self._last_wc = T_wc

    def _predict(self) -> Array:
        assert self._last_wc is not None
        return self._last_wc if self._delta is None else self._last_wc @ self._delta

    def _motion_prior(self) -> MotionPrior | None:
        """The motion model as the dynamic stage takes it (``T_cw`` form)."""
        if self._last_wc is None:
            return None
        velocity = None if self._delta is None else invert(self._delta)
        return MotionPrior(self._last_index, invert(self._last_wc), velocity)

    # ------------------------------------------------------------------ pose
    def _estimate(self, view: ViewFeatures, predicted: Array, timings: dict[str, float]) -> _PoseFit:
        """The pose against the configured reference, else the other one (see the module doc)."""
        refs = [self._kf_ref, self._last_ref]
        if self.cfg.reference == "frame":
            refs.reverse()
        t_match = t_pose = 0.0
        best = _PoseFit(None, np.zeros(0, bool), 0, np.zeros(0, np.intp), np.zeros((0, 3)))
        for k, ref in enumerate(r for r in refs if r is not None):
            for guided in self._searches:
                t0 = time.perf_counter()
                qi, ti = self._match(view, ref, predicted if guided else None, self.cfg.search_radius_px)
                t1 = time.perf_counter()
                T_cw, inl = solve_pnp(ref.pts_w[ti], view.xy[qi], self.camera.K, self.pnp)
                if T_cw is not None and not guided:  # re-match around the projections of this pose
                    t2 = time.perf_counter()
                    qi, ti = self._match(view, ref, invert(T_cw), REFINE_RADIUS_PX)
                    t1 += time.perf_counter() - t2
                    T_cw, inl = solve_pnp(ref.pts_w[ti], view.xy[qi], self.camera.K, self.pnp)
                t_match += t1 - t0
                t_pose += time.perf_counter() - t1
                if T_cw is not None:
                    self.counters["fallback_reference"] += int(k > 0)
                    best = _PoseFit(invert(T_cw), inl, len(qi), qi, ref.pts_w[ti])
                    break
            if best.T_wc is not None:
                break
        timings["match"] = t_match * 1e3
        timings["pose"] = t_pose * 1e3
        return best

    def _match(self, view: ViewFeatures, ref: _Reference, T_wc: Array | None, radius: float
               ) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
        """Matches (frame keypoint, reference keypoint with depth): near the projections of
        the reference's points from ``T_wc``, or by brute force without a pose."""
        with_depth = np.flatnonzero(ref.features.has_depth)
        if T_wc is None and self.range_matcher is not None:  # eq. 8: nearest descriptor in a window
            qi, ti, _ = self.range_matcher.match(view.xy, view.descriptors, ref.features.xy[with_depth],
                                                 ref.features.descriptors[with_depth])
            return qi, with_depth[ti]
        if T_wc is None:
            return match_views(view, ref.features, self.matcher, self.max_distance, self.cfg.ratio)
        pc = (ref.pts_w[with_depth] - T_wc[:3, 3]) @ T_wc[:3, :3]
        front = pc[:, 2] > 0.05
        with_depth, pc = with_depth[front], pc[front]
        cq, ct = pairs_within_radius(view.xy, self.camera.project(pc), radius)
        qi, ti, _ = self.matcher.match_candidates(view.descriptors, ref.features.descriptors, cq, with_depth[ct],
                                                  self.max_distance, self.cfg.ratio)
        return qi, ti

    # ------------------------------------------------------------------ keyframes
    def _needs_keyframe(self, T_wc: Array, n_inliers: int) -> bool:
        moved, turned = relative_motion(self.keyframes[-1].T_wc, T_wc)
        return bool(n_inliers < self.cfg.keyframe_min_inliers or moved > self.cfg.keyframe_max_translation_m
                    or turned > self.cfg.keyframe_max_rotation_deg)

    def _make_keyframe(self, packet: FramePacket, view: ViewFeatures, depth: NDArray[np.float32], T_wc: Array,
                       timings: dict[str, float], weight: float) -> None:
        t0 = time.perf_counter()
        tracks = np.full(len(view), -1, np.intp)
        if self.keyframes and self._kf_ref is not None:
            prev = self.keyframes[-1]
            if weight > REANCHOR_WEIGHT:  # a tracked pose: matches continue the previous keyframe's tracks
                qi, ti = self._match(view, self._kf_ref, T_wc, REFINE_RADIUS_PX)
                tracks[qi] = prev.tracks[ti]
            self.edges.append(Edge(len(self.keyframes) - 1, len(self.keyframes), invert(prev.T_wc) @ T_wc,
                                       float(weight), "tracking"))
        has = np.flatnonzero(view.has_depth)
        tracks[has] = self.tracks.add(len(self.keyframes), view.pts_c[has], tracks[has])
        kf = _Keyframe(len(self.keyframes), packet.frame.timestamp, T_wc.copy(), view, tracks)
        self.keyframes.append(kf)
        self._kf_ref = self._keyframe_reference(kf)
        self._announce(kf, depth)
        timings["keyframe"] = (time.perf_counter() - t0) * 1e3
        if self.cfg.global_correction and len(self.keyframes) % self.cfg.global_every == 0:
            t0 = time.perf_counter()
            self._global_correction(self.cfg.global_pairs)
            timings["global_correction"] = (time.perf_counter() - t0) * 1e3

    def _keyframe_reference(self, kf: _Keyframe) -> _Reference:
        """The keyframe's keypoints with world points: their tracks' fused positions (local
        correction) or, with it off, the keyframe's own back-projections."""
        pts_w = self._to_world(kf.features, kf.T_wc)
        if self.cfg.local_correction:
            has = np.flatnonzero(kf.features.has_depth)
            ids, pos = self.tracks.positions(self._poses(), kf.tracks[has], self.cfg.min_parallax_deg)
            pts_w[has] = pos[np.searchsorted(ids, kf.tracks[has])]
        return _Reference(kf.features, pts_w, kf.id)

    def _poses(self) -> Array:
        return np.stack([k.T_wc for k in self.keyframes]) if self.keyframes else np.zeros((0, 4, 4))

    def _announce(self, kf: _Keyframe, depth: NDArray[np.float32]) -> None:
        """The keyframe for the result, with the depth its points took."""
        if self.cfg.depth_alignment != "none":  # the frame's fit, as its points took it
            depth = self._alignment.apply(depth).astype(np.float32, copy=False)
        self._announced = KeyframeEvent(kf.id, kf.timestamp, kf.T_wc.copy(), depth)

    # ------------------------------------------------------------------ global correction
    def _global_correction(self, n_pairs: int) -> None:
        """Sampled keyframe pairs -> constraints -> pose graph -> keyframes, frames, maps."""
        self.counters["global_rounds"] += 1
        poses = self._poses()
        c = self.cfg
        pairs = candidate_pairs(poses, self._tried, c.global_every, n_pairs, self.rng, c.global_max_distance_m,
                                c.global_max_angle_deg)
        added = 0
        for i, j in pairs:
            self._tried.add((i, j))
            found = pair_constraint(self.keyframes[i].features, self.keyframes[j].features, self.matcher,
                                    self.max_distance, c.ratio, self.camera.K, self.pair_pnp)
            if found is not None:
                self.edges.append(Edge(i, j, found[0], found[1] / 100.0, "pair"))
                added += 1
        self.counters["global_pairs_tried"] += len(pairs)
        self.counters["global_constraints"] += added
        if added == 0:
            return
        try:
            corrected = correct_poses(poses, self.edges)
        except PoseGraphFailed:
            self.counters["pose_graph_failed"] += 1
            return
        self._apply_poses(corrected)

    def _apply_poses(self, corrected: Array) -> None:
        last_kf = self.keyframes[-1]
        T_kf_last = invert(last_kf.T_wc) @ self._last_wc if self._last_wc is not None else None
        for kf, T in zip(self.keyframes, corrected):
            kf.T_wc = T
        if T_kf_last is not None:
            self._last_wc = last_kf.T_wc @ T_kf_last
        self._kf_ref = self._keyframe_reference(last_kf)
        self._last_ref = None  # its points were placed with the old pose
        self._corrected = {kf.id: kf.T_wc.copy() for kf in self.keyframes}

    # ------------------------------------------------------------------ Tracker contract
    @property
    def n_keyframes(self) -> int:
        return len(self.keyframes)

    def trajectory(self) -> Trajectory:
        return Trajectory.from_poses([(t, self.keyframes[k].T_wc @ T_kc) for t, k, T_kc in self._frames])

    def keyframe_trajectory(self) -> Trajectory:
        return Trajectory.from_poses([(k.timestamp, k.T_wc) for k in self.keyframes])

    def map_points(self) -> Array:
        """One world position per feature track (the local data correction)."""
        if not self.keyframes:
            return np.zeros((0, 3))
        return self.tracks.positions(self._poses(), min_parallax_deg=self.cfg.min_parallax_deg)[1]

    def stats(self) -> dict[str, Any]:
        """Counters, and how far the depth source's scale and contrast wandered: the 5th, 50th
        and 95th percentiles of the depth alignment's fitted power and map / predicted ratio
        (1 and 1 for a depth that agrees with the map)."""
        fits = {}
        if self._fits:
            power, ratio = np.percentile(np.array(self._fits), [5, 50, 95], axis=0).T
            fits = {"depth_alignment_fits": len(self._fits), "depth_alignment_power_p5_p50_p95": power.round(4).tolist(),
                    "depth_alignment_ratio_p5_p50_p95": ratio.round(4).tolist()}
        return {"map_points": self.tracks.n_tracks, "tracking_edges": sum(e.kind == "tracking" for e in self.edges),
                **self.counters, **fits}

    def save_map(self, path: Path) -> None:
        raise ConfigError("--save-map needs a tracker with a map (tracking.method: orb_slam, e.g. --preset orb)")

    def shutdown(self) -> None:
        """A last global correction round over the pairs not tried yet; safe to call twice."""
        if self._stopped:
            return
        self._stopped = True
        if self.cfg.global_correction and len(self.keyframes) >= 3:
            self._global_correction(2 * self.cfg.global_pairs)

    def final_keyframe_poses(self) -> dict[int, Array]:
        return {kf.id: kf.T_wc.copy() for kf in self.keyframes}
