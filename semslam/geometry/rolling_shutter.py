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
``to_middle_row_with_depth_image`` is the RGB-D case: the depth frame is global, so depths
are read where the keypoints land, not under their raw pixels. The velocity comes from the
motion model, then from the tracked pose, then from ``backend/rolling_shutter_pose.py``
(``slam.rolling_shutter_refine`` / ``rolling_shutter_solve``; ``slam/orb/motion_priors/rolling_shutter.py``).
"""

from __future__ import annotations

from typing import Callable

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


def to_middle_row_with_depth_image(xy: NDArray[np.float64], fraction: NDArray[np.float64],
                                   velocity_cw: NDArray[np.float64], camera: PinholeCamera,
                                   depth_at: Callable[[NDArray[np.float64]], NDArray[np.floating]],
                                   iterations: int = 2) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """As ``to_middle_row`` for a rolling-shutter colour camera beside a global-shutter depth
    image taken at the middle row's time (RGB-D sensors register a global depth frame to the
    colour camera). The depth under a raw keypoint belongs to whatever was at that pixel at the
    middle row's time, not to the keypoint's point: on a 200 deg/s turn the two are up to
    ~30 px apart, across depth edges. So the keypoint is moved first (rotation), the depth read
    at the moved pixel (``depth_at``: undistorted pixels -> metres, 0 = none), and the move
    redone with that depth, ``iterations`` times. Returns (xy, depth) at the middle row's time."""
    if not len(xy):
        return xy.copy(), np.zeros(0)
    uv, _ = to_middle_row(xy, np.zeros(len(xy)), fraction, velocity_cw, camera)
    rotvec = Rotation.from_matrix(velocity_cw[:3, :3]).as_rotvec()
    z_mid = np.asarray(depth_at(uv), np.float64)
    for _ in range(iterations):
        # Depth of the point at its row's time, from its position at the middle row's time:
        # P_s = V^s P_mid (rotation by the scaled rotation vector, translation scaled).
        p_mid = camera.backproject(uv, z_mid)
        p_s = Rotation.from_rotvec(fraction[:, None] * rotvec[None, :]).apply(p_mid) \
            + fraction[:, None] * velocity_cw[:3, 3][None, :]
        z_s = np.where(z_mid > 0, p_s[:, 2], 0.0)
        uv, _ = to_middle_row(xy, z_s, fraction, velocity_cw, camera)
        z_mid = np.asarray(depth_at(uv), np.float64)
    return uv, z_mid
