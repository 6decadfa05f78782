"""A camera's rotation from matched map points when its centre is known (Wahba's problem).

On a motion-blurred frame the few matches left fix the full pose badly: rotation and
translation trade off along a far wall (a 6-DoF fit slides by decimetres where the camera
moved a centimetre). With the centre held where the motion says it is, three degrees of
freedom remain, and they are well fixed by a handful of bearings. The least-squares rotation
between bearing sets is scipy's ``Rotation.align_vectors`` (Markley's SVD solution); this
module adds the bearings and a trimmed re-fit against wrong matches. Pure functions.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

#: Reprojection thresholds (pixels, times the keypoint's pyramid scale) of the successive
#: trimmed fits: wide first (the starting rotation may be degrees off), then ORB-SLAM's
#: chi-square 95 % gate for 2 DoF (sqrt(5.991) = 2.45 px).
TRIM_PX = (12.0, 5.0, 5.991**0.5)


@dataclass(frozen=True)
class RotationFit:
    """``R_cw`` (world to camera), which matches it keeps, and whether enough did."""

    R_cw: NDArray[np.float64]
    inliers: NDArray[np.bool_]
    ok: bool


def bearings(xy: NDArray[np.float64], K: NDArray[np.float64]) -> NDArray[np.float64]:
    """Unit rays in the camera frame through pixels ``xy`` ``(N, 2)``."""
    rays = np.column_stack([(xy[:, 0] - K[0, 2]) / K[0, 0], (xy[:, 1] - K[1, 2]) / K[1, 1], np.ones(len(xy))])
    return rays / np.linalg.norm(rays, axis=1, keepdims=True)


def fit_rotation_about_centre(points_w: NDArray[np.float64], centre_w: NDArray[np.float64],
                              xy: NDArray[np.float64], K: NDArray[np.float64], R0_cw: NDArray[np.float64],
                              scale: NDArray[np.float64] | None = None, min_inliers: int = 6) -> RotationFit:
    """The rotation ``R_cw`` of a camera at ``centre_w`` that best maps the directions to
    ``points_w`` onto the rays through ``xy``, starting from ``R0_cw`` to pick the first
    inliers, then re-fitting on those within each of :data:`TRIM_PX` (times ``scale``, the
    keypoints' pyramid scales). ``ok`` is False, with ``R0_cw`` returned, when fewer than
    ``min_inliers`` matches survive."""
    n = len(points_w)
    scale = np.ones(n) if scale is None else np.asarray(scale, np.float64)
    rays = bearings(np.asarray(xy, np.float64), K)
    d = np.asarray(points_w, np.float64) - np.asarray(centre_w, np.float64)
    dist = np.linalg.norm(d, axis=1)
    front_ok = dist > 1e-9
    dirs = d / np.where(front_ok, dist, 1.0)[:, None]
    f = 0.5 * (K[0, 0] + K[1, 1])
    R = np.asarray(R0_cw, np.float64)
    keep = np.zeros(n, bool)
    for th in TRIM_PX:
        pred = dirs @ R.T
        cosang = np.clip(np.einsum("ij,ij->i", pred, rays), -1.0, 1.0)
        err_px = f * np.arccos(cosang)
        keep = front_ok & (pred[:, 2] > 0) & (err_px <= th * scale)
        if keep.sum() < min_inliers:
            return RotationFit(np.asarray(R0_cw, np.float64).copy(), keep, False)
        rot, _ = Rotation.align_vectors(rays[keep], dirs[keep])
        R = rot.as_matrix()
    pred = dirs @ R.T
    err_px = f * np.arccos(np.clip(np.einsum("ij,ij->i", pred, rays), -1.0, 1.0))
    return RotationFit(R, front_ok & (pred[:, 2] > 0) & (err_px <= TRIM_PX[-1] * scale), True)
