"""Foundation tracker: ORB matching against the last keyframe + PnP-RANSAC with depth.

Each keyframe keeps its keypoints with a valid depth as 3D points in the world. A new
frame is matched to them (guided by the constant-velocity prediction when there is one),
its pose solved by PnP-RANSAC (OpenCV, P3P hypotheses then Levenberg-Marquardt on the
inliers), and inliers whose measured depth disagrees with the pose are dropped. No local
map, no bundle adjustment: drift accumulates keyframe to keyframe.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from semslam.config import SystemConfig
from semslam.core.protocols import FramePacket, TrackerInputs
from semslam.core.types import DescriptorKind, Keypoints
from semslam.errors import ConfigError, DataError
from semslam.features import create_extractor
from semslam.core.trajectory import Trajectory
from semslam.features.matching import match_brute_force, match_candidates, pairs_within_radius
from semslam.frontend.keypoint_depth import sample_depth
from semslam.geometry.camera import PinholeCamera
from semslam.geometry.se3 import invert, make_pose, rotation_angle
from semslam.core.types import Frame
from semslam.core.types import TrackingState, TrackResult


@dataclass
class _Keyframe:
    timestamp: float
    pose_wc: NDArray[np.float64]
    points_w: NDArray[np.float64]
    descriptors: NDArray[np.uint8]


def _pose_to_rvec_tvec(pose_cw: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    rvec, _ = cv2.Rodrigues(pose_cw[:3, :3])
    return rvec.reshape(3, 1), pose_cw[:3, 3].reshape(3, 1).copy()


def _rvec_tvec_to_pose(rvec: NDArray[np.float64], tvec: NDArray[np.float64]) -> NDArray[np.float64]:
    rot, _ = cv2.Rodrigues(rvec)
    return make_pose(rot, tvec.reshape(3))


def create_tracker(config: SystemConfig, camera: PinholeCamera, inputs: TrackerInputs | None = None,
                   map_path: Path | None = None) -> "FrameToKeyframeTracker":
    """The registry's factory: refuses what this tracker cannot do, with the key to change."""
    if config.sensor != "rgbd":
        raise ConfigError(f"sensor: {config.sensor!r} is not supported by tracking.method=frame_to_keyframe "
                          "(RGB-D only; monocular: tracking.method=sdf_slam, --preset sdf)")
    if inputs is not None and inputs.dynamics is not None:
        raise ConfigError("dynamics: the frame_to_keyframe tracker has no dynamic-scene handling; "
                          "use tracking.method=orb_slam (e.g. --preset default)")
    if config.maps.builders:
        raise ConfigError("maps.builders: the frame_to_keyframe tracker feeds no map builders; "
                          "use tracking.method=orb_slam (e.g. --preset orb)")
    if map_path is not None:
        raise ConfigError("--load-map needs a tracker with a map (tracking.method: orb_slam, e.g. --preset orb)")
    return FrameToKeyframeTracker(config, camera)


class FrameToKeyframeTracker:
    """Tracks each frame against the current keyframe; see the module docstring."""

    has_map = False

    def __init__(self, config: SystemConfig, camera: PinholeCamera) -> None:
        self.cfg = config.frame_to_keyframe
        self.camera = camera
        self.extractor = create_extractor(config.features)
        if self.extractor.spec.kind is not DescriptorKind.BINARY:
            raise ConfigError("tracking.method: frame_to_keyframe matches binary descriptors "
                              "(frame_to_keyframe.max_hamming), features.extractor "
                              f"{config.features.extractor} makes float ones; use orb_slam")
        self.keyframe: _Keyframe | None = None
        self.n_keyframes = 0
        self._poses: list[tuple[float, NDArray[np.float64]]] = []  # every frame with a pose
        self._keyframe_poses: list[tuple[float, NDArray[np.float64]]] = []
        self._last_pose: NDArray[np.float64] | None = None
        self._velocity: NDArray[np.float64] | None = None  # T_last,prev: motion of the last step
        self._rng_seed = config.seed

    # -- helpers -----------------------------------------------------------------------
    def _points_with_depth(self, kps: Keypoints, depth: NDArray[np.float32]) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
        z = sample_depth(depth, kps.xy)
        valid = (z > self.cfg.min_depth_m) & (z < self.cfg.max_depth_m)
        pts_c = self.camera.backproject(self.camera.undistort_points(kps.xy), z)
        return pts_c, valid

    def _make_keyframe(self, frame: Frame, kps: Keypoints, pose_wc: NDArray[np.float64]) -> None:
        assert frame.depth is not None
        pts_c, valid = self._points_with_depth(kps, frame.depth)
        pts_w = pts_c[valid] @ pose_wc[:3, :3].T + pose_wc[:3, 3]
        self.keyframe = _Keyframe(frame.timestamp, pose_wc.copy(), pts_w, kps.descriptors[valid])
        self.n_keyframes += 1
        self._keyframe_poses.append((frame.timestamp, pose_wc.copy()))

    def _predict(self) -> NDArray[np.float64] | None:
        if self._last_pose is None:
            return None
        if self._velocity is None:
            return self._last_pose.copy()
        return self._last_pose @ self._velocity

    # -- main entry --------------------------------------------------------------------
    def prepare(self, frame: Frame) -> None:
        """Nothing runs ahead of tracking here."""

    def track(self, packet: FramePacket) -> TrackResult:
        frame = packet.frame
        if frame.depth is None:
            raise DataError(frame.rgb_path or "frame", "no depth image: the frame_to_keyframe tracker needs RGB-D frames")
        timings: dict[str, float] = {}
        t0 = time.perf_counter()
        kps = self.extractor.extract(frame.gray)
        timings["extract"] = (time.perf_counter() - t0) * 1e3

        if self.keyframe is None:
            pose = np.eye(4)
            _, valid = self._points_with_depth(kps, frame.depth)
            if valid.sum() < max(self.cfg.min_inliers, 50):
                return TrackResult(frame.timestamp, None, TrackingState.NOT_INITIALIZED, n_keypoints=len(kps),
                                   timings=timings, keypoints_xy=kps.xy)
            self._make_keyframe(frame, kps, pose)
            self._last_pose = pose
            self._poses.append((frame.timestamp, pose))
            return TrackResult(frame.timestamp, pose, TrackingState.OK, n_keypoints=len(kps), is_keyframe=True,
                               timings=timings, keypoints_xy=kps.xy)

        predicted = self._predict()
        pose, inliers, n_matches = self._estimate_pose(frame, kps, predicted, timings)
        n_inl = int(inliers.sum()) if inliers is not None else 0
        if pose is None or n_inl < self.cfg.min_inliers:
            pose = predicted if predicted is not None else self._last_pose
            state = TrackingState.LOST
            self._velocity = None
        else:
            state = TrackingState.OK
            if self._last_pose is not None:
                self._velocity = invert(self._last_pose) @ pose
        self._last_pose = pose

        is_kf = False
        if state is TrackingState.OK and self._needs_keyframe(pose, n_inl):
            t0 = time.perf_counter()
            self._make_keyframe(frame, kps, pose)
            timings["keyframe"] = (time.perf_counter() - t0) * 1e3
            is_kf = True
        # A lost frame keeps the prediction internally (to try again from there) but has no pose.
        pose_out = pose if state is TrackingState.OK else None
        if pose_out is not None:
            self._poses.append((frame.timestamp, pose_out))
        # The keypoints for viewers; this tracker removes nothing as dynamic.
        return TrackResult(frame.timestamp, pose_out, state, n_matches=n_matches, n_inliers=n_inl,
                           n_keypoints=len(kps), is_keyframe=is_kf, timings=timings, keypoints_xy=kps.xy)

    # -- Tracker contract --------------------------------------------------------------
    def trajectory(self) -> Trajectory:
        return Trajectory.from_poses(self._poses)

    def keyframe_trajectory(self) -> Trajectory:
        return Trajectory.from_poses(self._keyframe_poses)

    def map_points(self) -> NDArray[np.float64]:
        """No map: only the current keyframe's points, which are not a map."""
        return np.zeros((0, 3))

    def stats(self) -> dict[str, object]:
        return {}

    def save_map(self, path: Path) -> None:
        raise ConfigError("--save-map needs a tracker with a map (tracking.method: orb_slam, e.g. --preset orb)")

    def shutdown(self) -> None:
        """Nothing runs in the background."""

    def final_keyframe_poses(self) -> dict[int, NDArray[np.float64]]:
        """No keyframe is announced: this tracker feeds no maps (``create_tracker`` refuses them)."""
        return {}

    def _estimate_pose(self, frame: Frame, kps: Keypoints, predicted: NDArray[np.float64] | None,
                       timings: dict[str, float]) -> tuple[NDArray[np.float64] | None, NDArray[np.bool_] | None, int]:
        """Guided matching + PnP when the motion model predicts a pose; otherwise (or if
        that fails) unguided matching + PnP, then a guided re-match with the pose found,
        accepted only with ``min_inliers_unguided`` inliers (as ORB-SLAM's relocalisation)."""
        assert self.keyframe is not None and frame.depth is not None
        xy_und = self.camera.undistort_points(kps.xy)
        pose, inl, n_matches = None, None, 0
        t_match = t_pose = 0.0
        if predicted is not None:
            t0 = time.perf_counter()
            qi, ti = self._match_by_projection(kps, xy_und, predicted, self.cfg.search_radius_px)
            t_match += time.perf_counter() - t0
            if len(qi) >= 2 * self.cfg.min_inliers:
                t0 = time.perf_counter()
                pose, inl = self._solve_pose(qi, ti, xy_und, kps.xy, frame.depth)
                t_pose += time.perf_counter() - t0
                n_matches = len(qi)
        if pose is None or inl is None or inl.sum() < self.cfg.min_inliers:
            t0 = time.perf_counter()
            qi, ti, _ = match_brute_force(kps.descriptors, self.keyframe.descriptors, self.cfg.max_hamming, self.cfg.ratio)
            t_match += time.perf_counter() - t0
            t0 = time.perf_counter()
            pose, inl = self._solve_pose(qi, ti, xy_und, kps.xy, frame.depth)
            if pose is not None:
                qi, ti = self._match_by_projection(kps, xy_und, pose, self.cfg.refine_radius_px)
                pose, inl = self._solve_pose(qi, ti, xy_und, kps.xy, frame.depth)
            t_pose += time.perf_counter() - t0
            n_matches = len(qi)
            if inl is not None and inl.sum() < self.cfg.min_inliers_unguided:
                pose, inl = None, None
        timings["match"] = t_match * 1e3
        timings["pose"] = t_pose * 1e3
        return pose, inl, n_matches

    def _match_by_projection(self, kps: Keypoints, xy_und: NDArray[np.float64], pose_wc: NDArray[np.float64],
                             radius: float) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
        """Match keyframe points to keypoints near where ``pose_wc`` projects them."""
        kf = self.keyframe
        assert kf is not None
        pts_c = (kf.points_w - pose_wc[:3, 3]) @ pose_wc[:3, :3]
        front = np.nonzero(pts_c[:, 2] > 0.05)[0]
        proj = self.camera.project(pts_c[front])
        cq, ct = pairs_within_radius(xy_und, proj, radius)
        qi, ti, _ = match_candidates(kps.descriptors, kf.descriptors, cq, front[ct], self.cfg.max_hamming, self.cfg.ratio)
        return qi, ti

    def _solve_pose(self, qi: NDArray[np.intp], ti: NDArray[np.intp], xy_und: NDArray[np.float64],
                    xy_raw: NDArray[np.float32], depth: NDArray[np.float32]) -> tuple[NDArray[np.float64] | None, NDArray[np.bool_] | None]:
        """PnP-RANSAC on matched keyframe points, LM refinement, then a depth-consistency check."""
        assert self.keyframe is not None
        pts_w, xy, xy_raw = self.keyframe.points_w[ti], xy_und[qi], xy_raw[qi]
        if len(pts_w) < max(6, self.cfg.min_inliers):
            return None, None
        cv2.setRNGSeed(self._rng_seed)
        K = self.camera.K
        ok, rvec, tvec, idx = cv2.solvePnPRansac(
            pts_w.reshape(-1, 1, 3), xy.reshape(-1, 1, 2), K, None,
            iterationsCount=self.cfg.ransac_iterations, reprojectionError=self.cfg.ransac_reprojection_px,
            confidence=self.cfg.ransac_confidence, flags=cv2.SOLVEPNP_AP3P,
        )
        if not ok or idx is None or len(idx) < 4:
            return None, None
        inl = np.zeros(len(pts_w), bool)
        inl[idx.reshape(-1)] = True
        rvec, tvec = cv2.solvePnPRefineLM(pts_w[inl].reshape(-1, 1, 3), xy[inl].reshape(-1, 1, 2), K, None, rvec, tvec)
        pose_cw = _rvec_tvec_to_pose(rvec, tvec)
        # Depth check: the measured depth must agree with the point seen from the new pose.
        pts_c = pts_w @ pose_cw[:3, :3].T + pose_cw[:3, 3]
        z_meas = sample_depth(depth, xy_raw)
        has_z = z_meas > 0
        tol = self.cfg.depth_check_m + 0.03 * pts_c[:, 2]
        inl &= ~has_z | (np.abs(pts_c[:, 2] - z_meas) < tol)
        err = np.linalg.norm(self.camera.project(np.where(pts_c[:, 2:3] > 1e-6, pts_c, 1.0)) - xy, axis=1)
        inl &= (err < self.cfg.ransac_reprojection_px) & (pts_c[:, 2] > 0)
        if inl.sum() >= 6:
            rvec, tvec = cv2.solvePnPRefineLM(pts_w[inl].reshape(-1, 1, 3), xy[inl].reshape(-1, 1, 2), K, None, rvec, tvec)
            pose_cw = _rvec_tvec_to_pose(rvec, tvec)
        return invert(pose_cw), inl

    def _needs_keyframe(self, pose_wc: NDArray[np.float64], n_inliers: int) -> bool:
        assert self.keyframe is not None
        rel = invert(self.keyframe.pose_wc) @ pose_wc
        moved = np.linalg.norm(rel[:3, 3]) > self.cfg.keyframe_max_translation_m
        turned = np.degrees(rotation_angle(rel[:3, :3])) > self.cfg.keyframe_max_rotation_deg
        return bool(n_inliers < self.cfg.keyframe_min_inliers or moved or turned)
