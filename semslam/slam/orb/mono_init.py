"""Monocular map initialisation, a collaborator of ``Tracking`` (ORB-SLAM's
``Tracking::MonocularInitialization`` and ``CreateInitialMapMonocular``).

The first frame with more than ``MIN_KEYPOINTS`` keypoints becomes the reference (not a
keyframe). Each next frame is matched to it (``ORBmatcher::SearchForInitialization``: the same
pyramid level within ``WINDOW_PX`` of where the reference keypoint was last matched
(``mvbPrevMatched``: the windows follow the motion), ``th_low`` and a 0.9 ratio, then
rotation consistency); with fewer than ``MIN_MATCHES`` matches the reference is dropped (the
next frame becomes it); otherwise the two views are reconstructed
(``geometry/two_view.reconstruct``). On success two keyframes are made, the reference at the
origin and the current frame at ``T_21``, with a map point per triangulated match, scaled to a
median depth of 1 in the first keyframe.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from semslam.backend.bundle_adjustment import BAProblem, bundle_adjust
from semslam.core.protocols import Matcher
from semslam.geometry.camera import PinholeCamera
from semslam.geometry.two_view import TwoViewParams, TwoViewResult, normalise_initial_map, reconstruct
from semslam.slam.orb.frame_state import FrameState
from semslam.slam.orb.search import rotation_consistent

#: ORB-SLAM's constants (Tracking::MonocularInitialization, SearchForInitialization).
MIN_KEYPOINTS = 100
MIN_MATCHES = 100
#: Fewest points the refined initial map may keep (ORB-SLAM: TrackedMapPoints(1) < 50 resets).
MIN_REFINED = 50
WINDOW_PX = 100.0
RATIO = 0.9


@dataclass(frozen=True, eq=False)
class InitialPair:
    """A reconstruction that holds: reference/current keypoint indices of the triangulated
    matches, their world points (the reference's frame, median depth 1) and the current
    frame's ``T_cw`` (= ``T_21``, scaled)."""

    reference: FrameState
    idx_ref: NDArray[np.intp]
    idx_cur: NDArray[np.intp]
    points_w: NDArray[np.float64]
    T_cw: NDArray[np.float64]
    result: TwoViewResult


class MonocularInitializer:
    """Keeps the reference frame between attempts; ``attempt`` says when a pair holds."""

    def __init__(self, camera: PinholeCamera, matcher: Matcher, th_low: float, seed: int,
                 params: TwoViewParams | None = None, inv_sigma2: NDArray[np.float64] | None = None) -> None:
        self.camera = camera
        # Per pyramid level 1 / sigma^2 of a keypoint: with it, the pair is refined by a
        # two-view bundle adjustment before the map starts (ORB-SLAM's
        # CreateInitialMapMonocular runs GlobalBundleAdjustment, 20 iterations, first).
        self.inv_sigma2 = inv_sigma2
        self.matcher = matcher
        self.th_low = th_low
        self.rng = np.random.default_rng(seed)
        self.params = params or TwoViewParams()
        self.reference: FrameState | None = None
        #: Where each reference keypoint was last matched (ORB-SLAM's mvbPrevMatched): the
        #: centres of the next search windows.
        self.prev_xy = np.zeros((0, 2))
        self.attempts = 0
        self.reasons: dict[str, int] = {}  # why reconstructions were refused, counted

    def reset(self) -> None:
        self.reference = None

    def match(self, ref: FrameState, cur: FrameState, centres: NDArray[np.float64] | None = None
              ) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
        """SearchForInitialization: candidates at the reference keypoint's level within the
        window around ``centres`` (default: the reference keypoints), best by descriptor
        distance under ``th_low`` with the ratio test, one per current keypoint, then the
        rotation histogram."""
        grid = cur.grid(*self.camera.image_size)
        oct_ref = ref.keypoints.octave.astype(np.intp)
        n = len(ref)
        centres = ref.xy if centres is None else centres
        cq, ct = grid.pairs_in_radius(centres, np.full(n, WINDOW_PX), oct_ref, oct_ref, np.ones(len(cur), bool))
        qi, ti, _ = self.matcher.match_candidates(ref.keypoints.descriptors, cur.keypoints.descriptors, cq, ct, self.th_low, RATIO)
        qi, ti = np.asarray(qi, np.intp), np.asarray(ti, np.intp)
        keep = rotation_consistent(ref.keypoints.angle[qi], cur.keypoints.angle[ti])
        return qi[keep], ti[keep]

    def attempt(self, cur: FrameState) -> InitialPair | None:
        """One frame of ORB-SLAM's MonocularInitialization; the pair when it holds."""
        if self.reference is None:
            if len(cur) > MIN_KEYPOINTS:
                self.reference = cur
                self.prev_xy = cur.xy.copy()
            return None
        ref = self.reference
        if len(cur) <= MIN_KEYPOINTS:
            self.reset()
            return None
        i_ref, i_cur = self.match(ref, cur, self.prev_xy)
        self.prev_xy[i_ref] = cur.xy[i_cur]
        if len(i_ref) < MIN_MATCHES:
            # ORB-SLAM drops the initializer here: the next frame becomes the reference.
            self.reset()
            return None
        self.attempts += 1
        res = reconstruct(ref.xy[i_ref], cur.xy[i_cur], self.camera.K, self.rng, self.params)
        if not res.ok:
            self.reasons[res.reason] = self.reasons.get(res.reason, 0) + 1
            return None
        good = np.flatnonzero(res.triangulated)
        points, T_21 = res.points[good], res.T_21
        if self.inv_sigma2 is not None:
            keep, points, T_21 = self.refine(ref, cur, i_ref[good], i_cur[good], points, T_21)
            if keep.sum() < MIN_REFINED:  # ORB-SLAM: fewer than 50 tracked points resets
                self.reasons["too few points after bundle adjustment"] = (
                    self.reasons.get("too few points after bundle adjustment", 0) + 1)
                self.reset()
                return None
            good, points = good[keep], points[keep]
        try:
            pts, T_21, _ = normalise_initial_map(points, T_21)
        except ValueError:
            self.reset()
            return None
        return InitialPair(ref, i_ref[good], i_cur[good], pts, T_21, res)

    def refine(self, ref: FrameState, cur: FrameState, i_ref: NDArray[np.intp], i_cur: NDArray[np.intp],
               points: NDArray[np.float64], T_21: NDArray[np.float64]
               ) -> tuple[NDArray[np.bool_], NDArray[np.float64], NDArray[np.float64]]:
        """Two-view bundle adjustment of the pair (the reference fixed, 20 robust iterations as
        ORB-SLAM's initial global BA): the points that stay inliers in both views, all points'
        refined positions and the refined ``T_21``."""
        assert self.inv_sigma2 is not None
        n = len(points)
        cam = self.camera
        octave = np.concatenate([ref.keypoints.octave[i_ref], cur.keypoints.octave[i_cur]]).astype(np.intp)
        problem = BAProblem(
            poses_cw=np.stack([np.eye(4), T_21]), pose_fixed=np.array([True, False]), points_w=points,
            obs_pose=np.repeat(np.array([0, 1], np.intp), n), obs_point=np.tile(np.arange(n, dtype=np.intp), 2),
            uv=np.concatenate([ref.xy[i_ref], cur.xy[i_cur]]), ur=np.full(2 * n, -1.0),
            inv_sigma2=self.inv_sigma2[octave], fx=cam.fx, fy=cam.fy, cx=cam.cx, cy=cam.cy, bf=0.0)
        result = bundle_adjust(problem, iterations=(20, 0), remove_outliers=False)
        if not result.converged:
            return np.ones(n, bool), points, T_21
        keep = result.inlier_obs[:n] & result.inlier_obs[n:]
        return keep, result.points_w, result.poses_cw[1]
