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

from semslam.dynamics.masks import bounding_box, dilate
from semslam.geometry.camera import PinholeCamera


def plane_homography(T_kj: NDArray[np.float64], camera: PinholeCamera, depth_m: float) -> NDArray[np.float64]:
    """Pixels of j -> pixels of k for the plane z = depth_m in j: K (R + t n^T / d) K^-1."""
    K = camera.K
    H = T_kj[:3, :3] + np.outer(T_kj[:3, 3], (0.0, 0.0, 1.0 / depth_m))
    return K @ H @ np.linalg.inv(K)


def plane_depth(mask: NDArray[np.bool_], depth: NDArray[np.float32] | None) -> float | None:
    """The depth of the fronto-parallel plane a mask is warped on: the median measured depth
    under it (None without depth there). A source mask serves several skipped frames, so
    the caller keeps this (0.7 ms at 640x480) rather than recomputing it per frame."""
    if depth is None or not mask.any():
        return None
    z = depth[mask]
    z = z[z > 0]
    return float(np.median(z)) if z.size else None


def warp_mask(mask: NDArray[np.bool_], depth: NDArray[np.float32] | None, camera: PinholeCamera | None,
              T_kj: NDArray[np.float64] | None, margin_px: int = 0, depth_m: float | None = None
              ) -> NDArray[np.bool_]:
    """``mask`` of frame j seen from frame k (``T_kj`` maps j's camera coordinates to k's),
    grown by ``margin_px``. Without a pose, a camera or depth under the mask it stays where
    it was (then only the margin covers the motion). ``depth_m``: the plane's depth if the
    caller has it (``plane_depth``), else it is measured from ``depth``.

    Only the box the mask's bounding box lands in is warped (a person covers a fifth of the
    frame; ``cv2.warpPerspective`` costs ~2 ms for a whole 640x480 mask): the same pixels as
    warping the whole image, but for a destination pixel whose source coordinate falls
    within rounding error of a pixel boundary (tests/test_semantic_schedule.py)."""
    if T_kj is None or camera is None or not mask.any():
        return dilate(mask, margin_px)
    if depth_m is None:
        depth_m = plane_depth(mask, depth)
    if depth_m is None:
        return dilate(mask, margin_px)
    H = plane_homography(T_kj, camera, depth_m)
    h, w = mask.shape
    out = np.zeros((h, w), np.uint8)
    box = _warped_box(H, mask, w, h)
    if box is not None:
        x0, y0, x1, y1 = box
        shift = np.array([[1.0, 0.0, -x0], [0.0, 1.0, -y0], [0.0, 0.0, 1.0]])
        out[y0:y1, x0:x1] = cv2.warpPerspective(mask.view(np.uint8), shift @ H, (x1 - x0, y1 - y0),
                                                flags=cv2.INTER_NEAREST)
    return dilate(out.view(bool), margin_px)


def _warped_box(H: NDArray[np.float64], mask: NDArray[np.bool_], w: int, h: int
                ) -> tuple[int, int, int, int] | None:
    """(x0, y0, x1, y1): the destination pixels the mask's bounding box can land in under
    ``H``, clipped to the image (a pixel of margin for nearest-pixel rounding); the whole
    image if a corner maps behind the camera (the plane's horizon crosses the box); None if
    the box lands outside the image."""
    box = bounding_box(mask)
    assert box is not None  # warp_mask returned early for an empty mask
    r0, r1, c0, c1 = box
    xs = (c0 - 0.5, c1 - 0.5)
    ys = (r0 - 0.5, r1 - 0.5)
    corners = H @ np.array([[x, y, 1.0] for x in xs for y in ys]).T
    if not (corners[2] > 1e-9).all():
        return 0, 0, w, h
    u, v = corners[0] / corners[2], corners[1] / corners[2]
    x0, x1 = max(0, int(np.floor(u.min())) - 1), min(w, int(np.ceil(u.max())) + 2)
    y0, y1 = max(0, int(np.floor(v.min())) - 1), min(h, int(np.ceil(v.max())) + 2)
    if x0 >= x1 or y0 >= y1:
        return None
    return x0, y0, x1, y1


def relative_pose(T_cw_src: NDArray[np.float64] | None, T_cw_pred: NDArray[np.float64] | None
                  ) -> NDArray[np.float64] | None:
    """T_kj from the source frame's tracked pose and the predicted pose of frame k."""
    if T_cw_src is None or T_cw_pred is None:
        return None
    from semslam.geometry.se3 import invert

    return T_cw_pred @ invert(T_cw_src)
