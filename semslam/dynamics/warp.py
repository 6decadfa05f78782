"""Carry a dynamic mask from the last segmented frame to a later frame that was not segmented.

When the semantic thread skips a frame (it fell behind, or a forced stride), tracking still
needs a mask there. The mask of the last segmented frame j is forward-warped into frame k:
each masked pixel is back-projected with j's depth, moved by the relative pose T_kj (the
tracker's constant-velocity prediction) and projected into k. The pose explains the
camera's motion only, not the people's own: a margin (dilation) is there for that.
"""

from __future__ import annotations

import cv2
import numpy as np
from numpy.typing import NDArray

from semslam.dynamics.masks import dilate
from semslam.geometry.camera import PinholeCamera

_CLOSE = np.ones((3, 3), np.uint8)


def warp_mask(mask: NDArray[np.bool_], depth: NDArray[np.float32] | None, camera: PinholeCamera | None,
              T_kj: NDArray[np.float64] | None, margin_px: int = 0) -> NDArray[np.bool_]:
    """``mask`` of frame j seen from frame k (``T_kj`` maps j's camera coordinates to k's),
    grown by ``margin_px``. Without a pose or depth the mask stays where it was (then only
    the margin covers the motion). Masked pixels without depth move with the median depth
    of the others; forward splatting's one-pixel holes are closed (3x3)."""
    if T_kj is None or depth is None or camera is None or not mask.any():
        return dilate(mask, margin_px)
    h, w = mask.shape
    flat = np.flatnonzero(mask)  # np.nonzero on a 2-D mask is ~10x slower
    v, u = np.divmod(flat, w)
    z = depth.ravel()[flat].astype(np.float64)
    valid = z > 0
    if not valid.any():
        return dilate(mask, margin_px)
    if not valid.all():
        z[~valid] = np.median(z[valid])
    pts = np.stack([(u - camera.cx) / camera.fx * z, (v - camera.cy) / camera.fy * z, z])
    p = T_kj[:3, :3] @ pts + T_kj[:3, 3:4]
    front = p[2] > 1e-6
    p = p[:, front]
    u2 = np.rint(camera.fx * p[0] / p[2] + camera.cx).astype(np.intp)
    v2 = np.rint(camera.fy * p[1] / p[2] + camera.cy).astype(np.intp)
    inside = (u2 >= 0) & (u2 < w) & (v2 >= 0) & (v2 < h)
    out = np.zeros((h, w), np.uint8)
    out[v2[inside], u2[inside]] = 1
    out = cv2.morphologyEx(out, cv2.MORPH_CLOSE, _CLOSE)
    return dilate(out.astype(bool), margin_px)


def relative_pose(T_cw_src: NDArray[np.float64] | None, T_cw_pred: NDArray[np.float64] | None
                  ) -> NDArray[np.float64] | None:
    """T_kj from the source frame's tracked pose and the predicted pose of frame k."""
    if T_cw_src is None or T_cw_pred is None:
        return None
    from semslam.geometry.se3 import invert

    return T_cw_pred @ invert(T_cw_src)
