"""Carry a dynamic mask from the last segmented frame to a later frame that was not segmented.

When the semantic thread skips a frame (it fell behind, or a forced stride), tracking still
needs a mask there. The mask of the last segmented frame j is warped into frame k with the
relative pose T_kj (the tracker's constant-velocity prediction) and j's depth, taken as a
fronto-parallel plane at the mask's median depth: one homography, one OpenCV call that
releases the GIL. A per-pixel forward warp (every masked pixel with its own depth) gave the
same recall and excess on the walking renders (0.2-0.45 % of mask pixels differ: between
frames the camera moves a centimetre or two, so the parallax between people at different
depths is a pixel or two) but cost 4-6 ms median on the tracking thread under contention.
The pose explains the camera's motion only, not the people's own: a margin covers that.
"""

from __future__ import annotations

import cv2
import numpy as np
from numpy.typing import NDArray

from semslam.dynamics.masks import dilate
from semslam.geometry.camera import PinholeCamera


def plane_homography(T_kj: NDArray[np.float64], camera: PinholeCamera, depth_m: float) -> NDArray[np.float64]:
    """Pixels of j -> pixels of k for the plane z = depth_m in j: K (R + t n^T / d) K^-1."""
    K = camera.K
    H = T_kj[:3, :3] + np.outer(T_kj[:3, 3], (0.0, 0.0, 1.0 / depth_m))
    return K @ H @ np.linalg.inv(K)


def warp_mask(mask: NDArray[np.bool_], depth: NDArray[np.float32] | None, camera: PinholeCamera | None,
              T_kj: NDArray[np.float64] | None, margin_px: int = 0) -> NDArray[np.bool_]:
    """``mask`` of frame j seen from frame k (``T_kj`` maps j's camera coordinates to k's),
    grown by ``margin_px``. Without a pose, a camera or depth under the mask it stays where
    it was (then only the margin covers the motion)."""
    if T_kj is None or depth is None or camera is None or not mask.any():
        return dilate(mask, margin_px)
    z = depth[mask]
    z = z[z > 0]
    if z.size == 0:
        return dilate(mask, margin_px)
    H = plane_homography(T_kj, camera, float(np.median(z)))
    h, w = mask.shape
    out = cv2.warpPerspective(mask.view(np.uint8), H, (w, h), flags=cv2.INTER_NEAREST)
    return dilate(out.view(bool), margin_px)


def relative_pose(T_cw_src: NDArray[np.float64] | None, T_cw_pred: NDArray[np.float64] | None
                  ) -> NDArray[np.float64] | None:
    """T_kj from the source frame's tracked pose and the predicted pose of frame k."""
    if T_cw_src is None or T_cw_pred is None:
        return None
    from semslam.geometry.se3 import invert

    return T_cw_pred @ invert(T_cw_src)
