"""Keypoint-matching metrics of SDF-SLAM V-B (Tables 6 and 7), as functions of arrays.

* Ground-truth transfer (eqs. 5-7): a pixel of frame 1 with its depth is a point p1 in
  camera 1; with world->camera poses (q1, t1), (q2, t2) the same world point P is
  p2 = q2 q1^-1 (p1 - t1) + t2 in camera 2, projected to the pixel it must match.
* Table 6: a match is correct when the matched point of frame 2 lies within +-5 px (in x
  and in y, the paper's "plus and minus five pixels") of the transferred query point.
  Matches whose query pixel has no depth cannot be judged and are counted apart.
* Table 7 (eqs. 11-14): the relative pose is estimated from the matches by PnP-RANSAC on
  the depth of frame 1 (the paper's eq. 9: "3D to 2D minimization projection", the dataset
  has depth), then ΔT = T PT^-1 (eq. 11) and ΔR = R PR^-1 (eq. 13) against the true
  relative pose; errT = ||ΔT - E|| (eq. 12) and errR = ||ΔR - E|| (eq. 14), Frobenius
  norms. The paper's Table 7 gives them in % and deg/m (after [37], KITTI's odometry
  metric); those units are reported too, per metre travelled over all pairs: the sum of
  translation errors in % of the sum of true translations, and the sum of rotation errors
  in degrees per metre of it.
* Issue 12's Table 6 targets (``table6_targets``): FPFDCNN + range matcher at least ORB + BF
  on blurred pairs and at most 2 points below it on clear ones. The paper's own counts say
  which range matcher that is: of 500 points per image it matched 405 (clear) and 304
  (blurred), ORB + BF 329 and 249. Eq. 8 alone matches every point that has a candidate in
  its 140-px window (all of them on our pairs, clear or blurred), so the paper's matcher
  also rejected matches, and more of them under blur, as a cross-check does; our range
  matcher's mutual check (the same cross-check as the BF baseline's) keeps 72 / 65 % of the
  points on the benchmark pairs, the paper's 81 / 61 %. The target is judged on that row; eq. 8 alone is reported.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from semslam.geometry.camera import PinholeCamera
from semslam.geometry.se3 import invert, rotation_angle

__all__ = ["CORRECT_PX", "PairPose", "correct_matches", "lookup_depth", "pose_errors", "project",
           "relative_pose_pnp", "table6_targets", "transfer_points"]

CORRECT_PX = 5.0  # Table 6: correct within plus and minus five pixels
CLEAR_MARGIN_POINTS = 2.0  # issue 12: within 2 points of ORB + BF on clear pairs


def transfer_points(xy1: NDArray[np.floating], z1: NDArray[np.floating], camera: PinholeCamera,
                    T_wc1: NDArray[np.float64], T_wc2: NDArray[np.float64]
                    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Pixels (N, 2) of frame 1 with depths (N,) -> (pixels in frame 2 (N, 2), depth in
    camera 2 (N,)) by eqs. 5-7. Poses are camera->world (TUM ground truth), so
    (q, t) of eq. 5 is their inverse. Lens distortion is removed before and applied after."""
    T_c1w, T_c2w = invert(T_wc1), invert(T_wc2)
    q1, t1, q2, t2 = T_c1w[:3, :3], T_c1w[:3, 3], T_c2w[:3, :3], T_c2w[:3, 3]
    p1 = camera.backproject(camera.undistort_points(xy1), z1)  # eq. 5's p1
    p2 = (p1 - t1) @ q1 @ q2.T + t2  # eq. 7: q2 q1^-1 (p1 - t1) + t2 (q1^-1 = q1^T)
    return project(p2, camera), p2[:, 2]


def project(p_c: NDArray[np.floating], camera: PinholeCamera) -> NDArray[np.float64]:
    """Pixels (with the camera's distortion) of camera-frame points (z > 0)."""
    p_c = np.asarray(p_c, np.float64).reshape(-1, 3)
    if not camera.is_distorted or len(p_c) == 0:
        return camera.project(p_c)
    uv, _ = cv2.projectPoints(p_c, np.zeros(3), np.zeros(3), camera.K, camera.dist_coeffs)
    return uv.reshape(-1, 2)


def lookup_depth(depth: NDArray[np.float32], xy: NDArray[np.floating]) -> NDArray[np.float64]:
    """Depth at the nearest pixel of each position (0 outside the image or without depth)."""
    h, w = depth.shape
    ij = np.rint(np.asarray(xy, np.float64)).astype(np.int64).reshape(-1, 2)
    inside = (ij[:, 0] >= 0) & (ij[:, 0] < w) & (ij[:, 1] >= 0) & (ij[:, 1] < h)
    out = np.zeros(len(ij))
    out[inside] = depth[ij[inside, 1], ij[inside, 0]]
    return out


def correct_matches(xy_q: NDArray[np.floating], xy_t: NDArray[np.floating], depth1: NDArray[np.float32],
                    camera: PinholeCamera, T_wc1: NDArray[np.float64], T_wc2: NDArray[np.float64],
                    tol_px: float = CORRECT_PX) -> tuple[NDArray[np.bool_], NDArray[np.bool_]]:
    """(judged, correct) per match: judged where the query pixel has depth (and the point is
    in front of camera 2), correct where the matched pixel is within ``tol_px`` in x and y
    of the query's ground-truth transfer."""
    z1 = lookup_depth(depth1, xy_q)
    judged = np.zeros(len(z1), bool)
    correct = np.zeros(len(z1), bool)
    idx = np.flatnonzero(z1 > 0)
    if len(idx):
        xy2, z2 = transfer_points(np.asarray(xy_q)[idx], z1[idx], camera, T_wc1, T_wc2)
        err = np.abs(xy2 - np.asarray(xy_t, np.float64)[idx])
        judged[idx] = z2 > 0
        correct[idx] = (z2 > 0) & (err[:, 0] <= tol_px) & (err[:, 1] <= tol_px)
    return judged, correct


def relative_pose_pnp(xy1: NDArray[np.floating], z1: NDArray[np.floating], xy2: NDArray[np.floating],
                      camera: PinholeCamera, reprojection_px: float = 3.0, iterations: int = 200,
                      seed: int = 0, min_inliers: int = 6) -> tuple[NDArray[np.float64] | None, int]:
    """(T_c2c1 or None, inliers): PnP-RANSAC (eq. 9) on frame 1's points (pixels with depth)
    and their matches in frame 2; None with fewer than ``min_inliers`` inliers."""
    ok = np.asarray(z1) > 0
    if ok.sum() < max(4, min_inliers):
        return None, 0
    p1 = camera.backproject(camera.undistort_points(np.asarray(xy1)[ok]), np.asarray(z1)[ok])
    cv2.setRNGSeed(seed)
    found, rvec, tvec, inliers = cv2.solvePnPRansac(
        p1.astype(np.float64), np.asarray(xy2, np.float64)[ok], camera.K, camera.dist_coeffs,
        iterationsCount=iterations, reprojectionError=reprojection_px, confidence=0.999,
        flags=cv2.SOLVEPNP_EPNP)
    n_in = 0 if inliers is None else len(inliers)
    if not found or n_in < min_inliers:
        return None, n_in
    idx = inliers.reshape(-1)
    _, rvec, tvec = cv2.solvePnP(p1[idx], np.asarray(xy2, np.float64)[ok][idx], camera.K, camera.dist_coeffs,
                                 rvec, tvec, useExtrinsicGuess=True, flags=cv2.SOLVEPNP_ITERATIVE)
    T = np.eye(4)
    T[:3, :3] = cv2.Rodrigues(rvec)[0]
    T[:3, 3] = tvec.reshape(3)
    return T, n_in


@dataclass
class PairPose:
    """Eqs. 11-14 for one pair, with the units of Table 7 and plain ones."""

    err_t: float  # eq. 12, ||ΔT - E|| (Frobenius)
    err_r: float  # eq. 14, ||ΔR - E|| (Frobenius)
    trans_err_m: float  # |translation of ΔT|
    rot_err_deg: float  # angle of ΔR
    trans_err_pct: float  # 100 |Δt| / |t_true|
    rot_err_deg_per_m: float  # angle(ΔR) / |t_true|
    moved_m: float = 0.0  # |t_true|


def pose_errors(T_est: NDArray[np.float64], T_true: NDArray[np.float64]) -> PairPose:
    """Eqs. 11-14 for an estimated and a true relative pose (4x4, same convention)."""
    dT = T_true @ invert(T_est)  # eq. 11: T = ΔT PT
    dR = T_true[:3, :3] @ T_est[:3, :3].T  # eq. 13: R = ΔR PR
    e = np.eye(4)
    moved = float(np.linalg.norm(T_true[:3, 3]))
    t_err = float(np.linalg.norm(dT[:3, 3]))
    angle = float(np.degrees(rotation_angle(dR)))
    return PairPose(
        err_t=float(np.linalg.norm(dT - e)), err_r=float(np.linalg.norm(dR - e[:3, :3])),
        trans_err_m=t_err, rot_err_deg=angle,
        trans_err_pct=100.0 * t_err / moved if moved > 0 else float("nan"),
        rot_err_deg_per_m=angle / moved if moved > 0 else float("nan"), moved_m=moved)


@dataclass
class MethodScore:
    """Table 6 and 7 numbers of one method in one scenario (clear or blurred), summed over pairs."""

    method: str
    scenario: str
    pairs: int = 0
    points: int = 0  # keypoints of the first images
    matches: int = 0
    judged: int = 0  # matches whose query pixel has depth
    correct: int = 0
    pose_failures: int = 0  # pairs where PnP-RANSAC found no pose
    poses: list[PairPose] | None = None

    def add(self, n_points: int, judged: NDArray[np.bool_], correct: NDArray[np.bool_],
            pose: PairPose | None) -> None:
        self.pairs += 1
        self.points += int(n_points)
        self.matches += len(judged)
        self.judged += int(judged.sum())
        self.correct += int(correct.sum())
        if pose is None:
            self.pose_failures += 1
        else:
            self.poses = [*(self.poses or []), pose]

    def to_dict(self) -> dict[str, object]:
        """Table 6's rate (correct / judged matches) and Table 7's means over the pairs with a pose."""
        out: dict[str, object] = {
            "method": self.method, "scenario": self.scenario, "pairs": self.pairs,
            "points_per_image": self.points / max(self.pairs, 1), "matches": self.matches,
            "judged": self.judged, "correct": self.correct,
            "correct_rate": self.correct / self.judged if self.judged else None,
            "pose_failures": self.pose_failures,
        }
        poses = self.poses or []
        for key in ("err_t", "err_r", "trans_err_m", "rot_err_deg"):
            out[key] = float(np.mean([getattr(p, key) for p in poses])) if poses else None
        # Per metre travelled over all pairs (KITTI's rule, [37]): a mean of per-pair ratios
        # would be ruled by the pairs where the camera hardly moved.
        moved = sum(p.moved_m for p in poses)
        out["trans_err_pct"] = 100 * sum(p.trans_err_m for p in poses) / moved if moved > 0 else None
        out["rot_err_deg_per_m"] = sum(p.rot_err_deg for p in poses) / moved if moved > 0 else None
        return out


def table6_targets(rows: list[dict[str, object]], method: str,
                   reference: str = "orb+bf") -> list[dict[str, object]]:
    """Issue 12's Table 6 targets for ``method`` against ``reference`` (rows of
    ``MethodScore.to_dict``): >= on blurred pairs, at most 2 points below on clear ones.
    A scenario missing either row is left out."""
    rate = {(r["method"], r["scenario"]): r["correct_rate"] for r in rows}
    out: list[dict[str, object]] = []
    for scenario, margin in (("blurred", 0.0), ("clear", CLEAR_MARGIN_POINTS)):
        ours, ref = rate.get((method, scenario)), rate.get((reference, scenario))
        if ours is None or ref is None:
            continue
        gap = 100 * (float(ours) - float(ref))  # type: ignore[arg-type]
        need = f">= {reference}" if margin == 0 else f">= {reference} - {margin:g} points"
        out.append({"target": f"{scenario}: {method} {need}", "method": method, "scenario": scenario,
                    "value_pct": 100 * float(ours), "reference_pct": 100 * float(ref),  # type: ignore[arg-type]
                    "gap_points": gap, "met": gap >= -margin})
    return out
