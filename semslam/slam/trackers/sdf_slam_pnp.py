"""SDF-SLAM's pose from matches (IV-B, eqs. 9-10): 3D points from a reference's predicted
depth, their 2D matches in the new image, PnP-RANSAC then Levenberg-Marquardt on the inliers.

Shared by tracking (frame against its reference) and global data correction (keyframe
against keyframe). Pure functions of arrays; OpenCV does the solving. Eq. 10's
``pose = -R^-1 T`` is the camera centre of the ``[R | T]`` OpenCV returns: ``invert`` below.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from semslam.geometry.se3 import make_pose

Array = NDArray[np.float64]


@dataclass(frozen=True)
class PnpSettings:
    reprojection_px: float = 3.0
    iterations: int = 300
    confidence: float = 0.999
    min_inliers: int = 25
    seed: int = 0


def _pose(rvec: Array, tvec: Array) -> Array:
    rot, _ = cv2.Rodrigues(rvec)
    return make_pose(rot, np.asarray(tvec).reshape(3))


def solve_pnp(points: Array, xy: Array, K: Array, settings: PnpSettings
              ) -> tuple[Array | None, NDArray[np.bool_]]:
    """``T`` mapping ``points`` into the camera that sees them at undistorted ``xy``, and the
    inlier mask; (None, all False) with fewer than ``settings.min_inliers`` inliers.

    RANSAC on AP3P minimal sets (eq. 9's reprojection error under the threshold), LM on the
    inliers, then the inliers re-selected with the refined pose and refined once more.
    """
    n = len(points)
    inl = np.zeros(n, bool)
    if n < max(6, settings.min_inliers):
        return None, inl
    cv2.setRNGSeed(settings.seed)
    obj = np.ascontiguousarray(points, np.float64).reshape(-1, 1, 3)
    img = np.ascontiguousarray(xy, np.float64).reshape(-1, 1, 2)
    ok, rvec, tvec, idx = cv2.solvePnPRansac(obj, img, K, None, iterationsCount=settings.iterations,
                                             reprojectionError=settings.reprojection_px,
                                             confidence=settings.confidence, flags=cv2.SOLVEPNP_AP3P)
    if not ok or idx is None or len(idx) < settings.min_inliers:
        return None, inl
    inl[idx.reshape(-1)] = True
    rvec, tvec = cv2.solvePnPRefineLM(obj[inl], img[inl], K, None, rvec, tvec)
    T = _pose(rvec, tvec)
    pc = points @ T[:3, :3].T + T[:3, 3]
    front = pc[:, 2] > 1e-6
    proj = np.where(front[:, None], pc[:, :2] / np.where(front, pc[:, 2], 1.0)[:, None], 0.0)
    uv = proj * [K[0, 0], K[1, 1]] + [K[0, 2], K[1, 2]]
    inl = front & (np.linalg.norm(uv - xy, axis=1) < settings.reprojection_px)
    if inl.sum() < settings.min_inliers:
        return None, np.zeros(n, bool)
    rvec, tvec = cv2.solvePnPRefineLM(obj[inl], img[inl], K, None, rvec, tvec)
    return _pose(rvec, tvec), inl
