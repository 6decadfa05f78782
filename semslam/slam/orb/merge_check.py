"""Verifying a map merge before it is made (ORB-SLAM3 DetectCommonRegionsFromBoW's checks, RGB-D).

A merge moves a whole map by one transform; a wrong one leaves every frame of that map
off by as much as it is wrong, and nothing downstream (essential graph, global BA) can
undo a rigid offset that both maps agree on afterwards. So a candidate transform found by
place recognition (or by tracking's relocalisation hint) must pass, on the keyframe that
found it:

* a pose-only refit, matched again by projection at the refitted pose until it stops
  moving, with at least ``MIN_INLIERS`` inliers (relocalisation's bar);
* inliers spread over the image (``MIN_CELLS`` of a ``GRID`` of cells) and in depth
  (``MIN_DEPTH_SPREAD``): a patch of repeated texture or one wall can fit a wrong pose;
* the depths the keyframe measured at the inliers agree with the transformed map points'
  depths (median relative error <= ``MAX_DEPTH_ERROR``): RGB-D sees the distance, so a
  transform that slides along the view is caught;

and then be confirmed by ``COINCIDENCES`` keyframes in all (ORB-SLAM3's
mnMergeNumCoincidences = 3), of both maps: each of the keyframe's covisibles (ORB-SLAM3's
check) and of the candidate's covisibles, placed with the transform,
must find the other map's points (``MIN_PROJECTED``), pass the depth check, and refit to a
pose that sees the scene within ``AGREE_M`` / ``AGREE_DEG`` of where the transform put it. Keyframes made later
in the same map confirm a pending transform the same way (``PendingMerge``), as
ORB-SLAM3's DetectAndReffineSim3FromLastKF does; ``PENDING_MISSES`` failures in a row
drop it.

Monocular maps (``MergeVerifier(mono=True)``): the transform is a similarity (ORB-SLAM3
MergeLocal's Sim3 for a monocular map; its scale from loop closing's 7-DoF RANSAC and
OptimizeSim3) and there is no depth to compare with. A keyframe is placed in the other map's
world by the similarity's rigid part (``place``), refitted pose-only on reprojection alone,
and the scale rides along from the Sim(3). The depth agreement compares the refit's depths
with the keyframe's own map points at the same keypoints, divided by the similarity's scale
(``own_depths``, ``MAX_MONO_DEPTH_ERROR``): keyframes near each other agree on a wrong
scale (their refits hardly move), the depths do not. The rest holds as for RGB-D: inliers,
spread in the image and in depth, and ``COINCIDENCES`` keyframes of both maps whose refits
land where the similarity put them. ``AGREE_M`` is then in the other map's units (a
monocular map starts at median depth 1, so 5 % of the scene's depth).

Pure numpy here; the map-side matching is passed in by loop closing.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from semslam.backend.pose_only import optimize_pose
from semslam.backend.sim3 import rigid_part, sim3_inverse, sim3_parts
from semslam.geometry.camera import PinholeCamera
from semslam.geometry.se3 import invert, orthonormalize, rotation_angle
from semslam.slam.orb.map import KeyFrame
from semslam.slam.orb.point_store import MapPoint

#: Pose-only inliers the keyframe that found the place needs (relocalisation's bar).
MIN_INLIERS = 50
#: The finder's refit is repeated (matching again at the refitted pose) up to REFITS times
#: until it moves the scene by at most CONVERGED_M.
REFITS = 3
CONVERGED_M = 0.01
#: Inliers a confirming keyframe needs (ORB-SLAM3's nProjMatches for the covisibles).
MIN_PROJECTED = 30
#: The image is cut into GRID x GRID cells; inliers must fall in MIN_CELLS of them.
GRID = 4
MIN_CELLS = 5
#: (90th - 10th percentile) / median of the inliers' depths, at least.
MIN_DEPTH_SPREAD = 0.10
#: Median |measured - predicted| / measured depth of the inliers, at most.
MAX_DEPTH_ERROR = 0.04
#: Monocular: the same against the keyframe's own triangulated points, which scatter more
#: (right merges measured 0.036-0.044 on blackout_xyz renders; the same with the scale 15 %
#: off: 0.15).
MAX_MONO_DEPTH_ERROR = 0.08
#: Keyframes that must agree on the transform (the finder included).
COINCIDENCES = 3
#: A confirming keyframe's refit may move the scene it sees (``scene_shift``) and turn
#: from its predicted pose by this much.
AGREE_M = 0.05
AGREE_DEG = 2.0
#: Best covisibles of the finder tried as confirmations.
COVISIBLES = 5
#: Later keyframes failing in a row before a pending transform is dropped (ORB-SLAM3 gives
#: up after 2 of its keyframes; here a keyframe of either map may try, hence one more).
PENDING_MISSES = 3

log = logging.getLogger(__name__)

Matcher = Callable[[KeyFrame, KeyFrame, NDArray[np.float64]], dict[int, MapPoint] | None]


def enough(confirmers: set[tuple[int, int]], later: bool = False) -> bool:
    """``COINCIDENCES`` keyframes agree, from both maps or including one made after the
    transform was found (``later``): keyframes of one map placed together agree with each
    other when they share an error (a young map's last keyframes, placed before local
    mapping caught up, seen to fit 17 cm / 6 deg off the truth together); a keyframe
    tracked afterwards is placed on its own."""
    return len(confirmers) >= COINCIDENCES and (later or len({m for m, _ in confirmers}) > 1)


def grid_cells(uv: NDArray[np.float64], size: tuple[float, float], grid: int = GRID) -> int:
    """How many cells of a grid x grid cut of the image hold at least one of ``uv``."""
    if len(uv) == 0:
        return 0
    w, h = size
    cx = np.clip((uv[:, 0] * grid / w).astype(int), 0, grid - 1)
    cy = np.clip((uv[:, 1] * grid / h).astype(int), 0, grid - 1)
    return len(np.unique(cy * grid + cx))


def depth_spread(z: NDArray[np.float64]) -> float:
    """(90th - 10th percentile) / median of the depths: 0 for points at one distance."""
    z = z[z > 0]
    if len(z) < 3:
        return 0.0
    p10, p50, p90 = np.percentile(z, [10, 50, 90])
    return float((p90 - p10) / p50)


def depth_error(z_measured: NDArray[np.float64], z_predicted: NDArray[np.float64]) -> float:
    """Median relative error of the predicted depths where a depth was measured (inf if none)."""
    ok = z_measured > 0
    if not ok.any():
        return float("inf")
    return float(np.median(np.abs(z_predicted[ok] - z_measured[ok]) / z_measured[ok]))


def scene_shift(A: NDArray[np.float64], B: NDArray[np.float64], pts_w: NDArray[np.float64]) -> float:
    """Median distance between where camera poses A and B (T_cw) put the points ``pts_w``
    in the camera: how far apart the two poses' views of that scene are. A small turn about
    the scene (what a map's own drift between neighbouring keyframes looks like) moves the
    centre by centimetres but the viewed points hardly; a transform off by a period of a
    repeated texture moves them all by that period."""
    if len(pts_w) == 0:
        return float("inf")
    D = A - B
    return float(np.median(np.linalg.norm(pts_w @ D[:3, :3].T + D[:3, 3], axis=1)))


def own_depths(kf: KeyFrame, idx: NDArray[np.intp]) -> NDArray[np.float64]:
    """Depths in kf's camera of kf's own map points at keypoints ``idx`` (0 where it has none):
    a monocular keyframe's stand-in for measured depths."""
    z = np.zeros(len(idx))
    R, t = kf.T_cw[:3, :3], kf.T_cw[:3, 3]
    for j, i in enumerate(idx.tolist()):
        p = kf.points[i]
        if p is not None and not p.bad:
            z[j] = float(R[2] @ p.pos + t[2])
    return z


def similarity_scale(S: NDArray[np.float64]) -> float:
    """The scale ``s`` of ``S = [[s R, t], [0, 1]]`` (1 for a rigid transform)."""
    return sim3_parts(S)[2]


def place(T_cw: NDArray[np.float64], S: NDArray[np.float64], mono: bool) -> NDArray[np.float64]:
    """The camera pose ``T_cw`` (its map's world) in another map's world, ``S`` (this world
    <- that world): ``T_cw @ S``, of which a monocular map keeps the rigid part (the camera
    in the other map's units, seeing every point at the same pixel)."""
    return rigid_part(T_cw @ S) if mono else T_cw @ S


def with_scale(T: NDArray[np.float64], s: float) -> NDArray[np.float64]:
    """``diag(s, s, s, 1) @ T``: a rigid camera transform in another map's units made the
    similarity into this map's (camera coordinates scaled by ``s``)."""
    out = T.copy()
    out[:3] *= s
    out[3] = (0.0, 0.0, 0.0, 1.0)
    return out


def pose_difference(A: NDArray[np.float64], B: NDArray[np.float64]) -> tuple[float, float]:
    """(metres, degrees) between two camera poses T_cw: the centres' distance and the angle
    of the relative rotation."""
    c_a, c_b = invert(A)[:3, 3], invert(B)[:3, 3]
    angle = np.degrees(rotation_angle(A[:3, :3] @ B[:3, :3].T))
    return float(np.linalg.norm(c_a - c_b)), float(angle)


@dataclass
class Fit:
    """A keyframe refitted on the other map's points: its pose in the other map's world
    (``T_cw``), the inlier matches, and the checks' measurements."""

    T_cw: NDArray[np.float64]
    matched: dict[int, MapPoint]
    points: NDArray[np.float64]  # the inliers' positions (the other map's world)
    cells: int
    spread: float
    depth_err: float


@dataclass
class Verdict:
    """A checked candidate: ``reason`` is None when it passed, else why not."""

    reason: str | None
    S: NDArray[np.float64] | None = None  # kf's world <- cand's world, from the finder's refit
    points: NDArray[np.float64] | None = None  # the finder's inliers (cand's world)
    T12: NDArray[np.float64] | None = None  # kf camera <- cand camera
    matched: dict[int, MapPoint] = field(default_factory=dict)
    confirmers: set[tuple[int, int]] = field(default_factory=set)  # (map, keyframe id) of those that agree, kf included

    @property
    def ok(self) -> bool:
        return self.reason is None


@dataclass
class PendingMerge:
    """A transform between two maps confirmed by fewer than ``COINCIDENCES`` keyframes,
    waiting for later keyframes of either map to confirm it."""

    kf: KeyFrame  # the finder (map a)
    cand: KeyFrame  # its match in the other map (map b)
    S: NDArray[np.float64]  # a's world <- b's world
    points: NDArray[np.float64]  # the finder's inliers (b's world)
    confirmers: set[tuple[int, int]]  # (map, keyframe id) of those that agreed so far (each counts once)
    later: bool = False  # a keyframe made after the finding agreed
    misses: int = 0
    mono: bool = False  # S is a similarity (monocular maps)

    @property
    def coincidences(self) -> int:
        return len(self.confirmers)

    @property
    def enough(self) -> bool:
        return enough(self.confirmers, self.later)

    def agrees(self, S: NDArray[np.float64]) -> bool:
        """Does ``S`` (a's world <- b's world) show the finder the scene where this one does?"""
        A, B = place(self.kf.T_cw, S, self.mono), place(self.kf.T_cw, self.S, self.mono)
        return scene_shift(A, B, self.points) <= AGREE_M and pose_difference(A, B)[1] <= AGREE_DEG


class MergeVerifier:
    """Checks candidate merge transforms; ``match`` projects cand's neighbourhood into a
    keyframe placed at a pose (loop closing's verification by projection). ``mono``: the
    maps are monocular (similarities, no depth check)."""

    def __init__(self, camera: PinholeCamera, bf: float, inv_sigma2: NDArray[np.float64], match: Matcher,
                 mono: bool = False) -> None:
        self.camera = camera
        self.bf = bf
        self.inv_sigma2 = inv_sigma2
        self.match = match
        self.mono = mono
        self.max_depth_error = MAX_MONO_DEPTH_ERROR if mono else MAX_DEPTH_ERROR

    def inverse(self, S: NDArray[np.float64]) -> NDArray[np.float64]:
        """The inverse of a transform between two maps' worlds."""
        return sim3_inverse(S) if self.mono else invert(S)

    def relative(self, fit: "Fit", other: KeyFrame, S: NDArray[np.float64]) -> NDArray[np.float64]:
        """``T12`` (the refitted keyframe's camera <- other's camera) of a refit whose
        keyframe was placed by ``S`` (its world <- other's world): with the similarity's
        scale in a monocular map (the refit is in other's units)."""
        T12 = fit.T_cw @ other.T_wc
        return with_scale(T12, similarity_scale(S)) if self.mono else T12

    def fit(self, kf: KeyFrame, T_cw0: NDArray[np.float64], matched: dict[int, MapPoint], scale: float = 1.0
            ) -> Fit | None:
        """Pose-only refit of kf from ``T_cw0`` (kf in the other map's world) on ``matched``
        (kf keypoint -> point of the other map); None without enough valid matches.
        ``scale``: kf's map units per the other map's (monocular)."""
        pairs = [(i, p) for i, p in matched.items() if not p.bad]
        if len(pairs) < MIN_PROJECTED:
            return None
        idx = np.fromiter((i for i, _ in pairs), np.intp, len(pairs))
        pos = np.array([p.pos for _, p in pairs]).reshape(-1, 3)
        cam = self.camera
        res = optimize_pose(T_cw0, pos, kf.xy[idx], kf.ur[idx], self.inv_sigma2[kf.keypoints.octave[idx]],
                            cam.fx, cam.fy, cam.cx, cam.cy, self.bf)
        T = orthonormalize(res.T_cw)
        inl = np.asarray(res.inliers, bool)
        z_pred = pos[inl] @ T[2, :3] + T[2, 3]
        if self.mono:
            # No sensor depth: kf's own map's points at the same keypoints stand in for it,
            # brought to the other map's units by the similarity's scale (a wrong scale fails here).
            err = depth_error(own_depths(kf, idx[inl]) / scale, z_pred)
        else:
            err = depth_error(kf.depth[idx[inl]].astype(np.float64), z_pred)
        return Fit(T, {int(i): p for (i, p), ok in zip(pairs, inl) if ok}, pos[inl],
                   grid_cells(kf.xy[idx[inl]], cam.image_size), depth_spread(z_pred), err)

    def converge(self, kf: KeyFrame, cand: KeyFrame, T_cw0: NDArray[np.float64], matched: dict[int, MapPoint],
                 scale: float = 1.0) -> Fit | None:
        """Refit kf on cand's neighbourhood until the pose stops moving (ORB-SLAM3 matches
        again by projection at the optimised Sim3 and optimises once more): a pose-only fit
        from a transform 10-20 cm off stops short of the truth on the matches found near the
        wrong pose. None if it still moves the scene by over ``CONVERGED_M`` after
        ``REFITS`` rounds (or finds nothing); a fit too small to pass is returned as is."""
        fit = self.fit(kf, T_cw0, matched, scale)
        for _ in range(REFITS):
            if fit is None or len(fit.matched) < MIN_INLIERS:
                return fit
            moved = scene_shift(fit.T_cw, T_cw0, fit.points)
            if moved <= CONVERGED_M:
                return fit
            T_cw0 = fit.T_cw
            again = self.match(kf, cand, T_cw0 @ cand.T_wc)
            fit = self.fit(kf, T_cw0, again, scale) if again else None
        return None

    def check_finder(self, fit: Fit | None) -> str | None:
        """Why the finding keyframe's refit fails, or None."""
        if fit is None or len(fit.matched) < MIN_INLIERS:
            return "inliers"
        if fit.cells < MIN_CELLS:
            return "image_spread"
        if fit.spread < MIN_DEPTH_SPREAD:
            return "depth_spread"
        if fit.depth_err > self.max_depth_error:
            return "depth_agreement"
        return None

    def confirm(self, k: KeyFrame, cand: KeyFrame, S: NDArray[np.float64]) -> Fit | None:
        """Keyframe ``k``, placed in cand's world by ``S`` (k's world <- cand's world): its
        refit on cand's neighbourhood if it finds it, passes the depth check and lands within
        ``AGREE_M`` / ``AGREE_DEG`` of where ``S`` put it; else None."""
        T_pred = place(k.T_cw, S, self.mono)
        matched = self.match(k, cand, T_pred @ cand.T_wc)
        scale = similarity_scale(S) if self.mono else 1.0
        fit = self.fit(k, T_pred, matched, scale) if matched else None
        if fit is None or len(fit.matched) < MIN_PROJECTED or fit.depth_err > self.max_depth_error:
            log.debug("kf %d does not confirm vs %d: %s", k.id, cand.id,
                      "no matches" if fit is None else f"{len(fit.matched)} inliers, depth error {fit.depth_err:.3f}")
            return None
        shift = scene_shift(fit.T_cw, T_pred, fit.points)
        _, angle = pose_difference(fit.T_cw, T_pred)
        log.debug("kf %d vs %d: refit moves the scene %.3f m, %.2f deg from the transform, %d inliers", k.id,
                  cand.id, shift, angle, len(fit.matched))
        return fit if shift <= AGREE_M and angle <= AGREE_DEG else None

    def verify(self, kf: KeyFrame, cand: KeyFrame, T12: NDArray[np.float64], matched: dict[int, MapPoint],
               covisibles: list[KeyFrame], cand_covisibles: list[KeyFrame] = ()) -> Verdict:
        """Check a candidate (``T12``: kf camera <- cand camera, ``matched``: kf keypoint ->
        cand-side point) on kf, then count the keyframes that confirm it: kf's covisibles
        placed in cand's world, and cand's covisibles placed in kf's world (``enough``: some
        of each map; a young map may have no covisibles yet). Monocular: ``T12`` is a
        similarity; kf is refitted rigidly in cand's units and keeps its scale."""
        s12 = similarity_scale(T12) if self.mono else 1.0
        T_cw0 = rigid_part(T12 @ cand.T_cw) if self.mono else T12 @ cand.T_cw
        fit = self.converge(kf, cand, T_cw0, matched, s12)
        reason = self.check_finder(fit) if fit is not None else "not_converged"
        if fit is not None:
            log.debug("merge check kf %d vs %d: %d inliers, %d cells, depth spread %.2f, depth error %.3f: %s",
                      kf.id, cand.id, len(fit.matched), fit.cells, fit.spread, fit.depth_err, reason or "passed")
        if reason is not None or fit is None:
            return Verdict(reason)
        # kf's world <- cand's world (monocular: the refit's camera coordinates times the scale)
        S = kf.T_wc @ with_scale(fit.T_cw, s12) if self.mono else kf.T_wc @ fit.T_cw
        agree = {(kf.map_id, kf.id)}
        for k in covisibles[:COVISIBLES]:
            if enough(agree):
                break
            if self.confirm(k, cand, S) is not None:
                agree.add((k.map_id, k.id))
        S_inv = self.inverse(S)
        for k in cand_covisibles[:COVISIBLES]:
            if enough(agree):
                break
            if self.confirm(k, kf, S_inv) is not None:
                agree.add((k.map_id, k.id))
        return Verdict(None, S, fit.points, self.relative(fit, cand, S), fit.matched, agree)
