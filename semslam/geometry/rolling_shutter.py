"""Rolling shutter: keypoints moved to the time of the image's middle row.

A rolling-shutter camera reads its rows out one after the other over ``readout`` seconds,
so during a fast turn the top and bottom of one image see the scene from different poses
(a 200 deg/s turn with a 30 ms readout shears the image by ~6 degrees, ~55 px at 640x480),
and a global-shutter pose fit finds most matches outliers. With the camera's velocity (the
motion model's, constant over a frame), a keypoint seen at raw row ``v`` was captured
``s = readout (v / (H - 1) - 1/2) / dt`` frame intervals after the middle row; its point,
moved back by that fraction of the inter-frame motion, is where a global shutter at the
middle row's time (the frame's timestamp) would have seen it.

``velocity_cw`` maps camera coordinates of the earlier frame to the later one (``T_cw(t+dt)
= V T_cw(t)``). Fractional motion: rotation by the scaled rotation vector, translation
scaled linearly (first order; exact for rotation, within millimetres for the translations
of one frame). Points without depth are moved by the rotation only (their ray).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from semslam.geometry.camera import PinholeCamera


def row_time_fraction(rows: NDArray[np.floating], height: int, readout_s: float, frame_dt_s: float
                      ) -> NDArray[np.float64]:
    """Frame intervals between each raw row's capture and the middle row's (negative above)."""
    return readout_s * (np.asarray(rows, np.float64) / max(height - 1, 1) - 0.5) / frame_dt_s


def to_middle_row(xy: NDArray[np.float64], depth: NDArray[np.floating], fraction: NDArray[np.float64],
                  velocity_cw: NDArray[np.float64], camera: PinholeCamera
                  ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Undistorted pixels ``xy`` (N, 2) and depths (0 = none) captured ``fraction`` frame
    intervals after the middle row, as seen at the middle row's time: (xy, depth)."""
    if not len(xy):
        return xy.copy(), np.asarray(depth, np.float64).copy()
    rotvec = Rotation.from_matrix(velocity_cw[:3, :3]).as_rotvec()
    # Camera at the keypoint's time = V^s * (camera at the middle row): undo V^s.
    back = Rotation.from_rotvec(-fraction[:, None] * rotvec[None, :])
    z = np.asarray(depth, np.float64)
    has_z = z > 0
    rays = np.stack([(xy[:, 0] - camera.cx) / camera.fx, (xy[:, 1] - camera.cy) / camera.fy, np.ones(len(xy))], 1)
    pts = rays * np.where(has_z, z, 1.0)[:, None]
    # P_mid = R_s^T (P_s - t_s), with V^s ~ (R_s, s t): translation only where depth is known.
    shift = fraction[:, None] * velocity_cw[:3, 3][None, :] * has_z[:, None]
    moved = back.apply(pts - shift)
    out_z = np.where(has_z, moved[:, 2], 0.0)
    ok = moved[:, 2] > 1e-9
    uv = xy.copy()
    uv[ok, 0] = camera.fx * moved[ok, 0] / moved[ok, 2] + camera.cx
    uv[ok, 1] = camera.fy * moved[ok, 1] / moved[ok, 2] + camera.cy
    return uv, out_z
