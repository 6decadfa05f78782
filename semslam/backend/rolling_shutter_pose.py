"""Pose and velocity of a rolling-shutter frame, fitted together (rolling-shutter VO).

Moving keypoints to the middle row's time (``geometry/rolling_shutter.py``) needs the
camera's velocity during the frame. The velocity between the last frame and this one is an
average over the previous frame interval: wrong where a turn starts or stops (at ~200 deg/s
a turn reaches full speed in a few frames), and then every keypoint is moved by the wrong
amount. But a rolling-shutter image observes its own velocity: each row is a view from a
different pose. So this fits ``T_cw`` (the middle row's pose) and ``V`` (the motion over
one frame interval, ``T_cw(t + dt) = V T_cw(t)``) to the raw observations, each projected
with its row's pose ``V^s T_cw`` (``s`` from ``row_time_fraction``; ``V^s`` scales the
rotation vector and the translation, as the module above does). A weak prior keeps ``V``
near the motion model's guess where the rows' spread says little.

Gauss-Newton with Huber weights on 2D residuals (12 unknowns: a left increment of the pose
and the velocity's rotation vector and translation), two rounds as ORB-SLAM's pose-only
optimisation (the second without the first one's outliers). Numpy.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.linalg import cho_factor, cho_solve
from scipy.spatial.transform import Rotation

from semslam.backend.gtsam_utils import CHI2_MONO

Array = NDArray[np.float64]


@dataclass(frozen=True)
class RollingShutterPose:
    """The fitted middle-row pose, the velocity per frame interval, and the inliers."""

    T_cw: Array
    velocity_cw: Array
    inliers: NDArray[np.bool_]


def _twist(V: Array) -> Array:
    """(rotation vector, translation) of a motion ``V`` (the fraction model's coordinates)."""
    return np.concatenate([Rotation.from_matrix(V[:3, :3]).as_rotvec(), V[:3, 3]])


def _from_twist(xi: Array) -> Array:
    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec(xi[:3]).as_matrix()
    T[:3, 3] = xi[3:]
    return T


def _rotate(rotvecs: Array, pts: Array) -> Array:
    """Each point rotated by its own rotation vector (Rodrigues, vectorised)."""
    theta = np.linalg.norm(rotvecs, axis=1)
    safe = np.where(theta > 1e-12, theta, 1.0)
    k = rotvecs / safe[:, None]
    c, s = np.cos(theta)[:, None], np.sin(theta)[:, None]
    return pts * c + np.cross(k, pts) * s + k * (k * pts).sum(1, keepdims=True) * (1 - c)


def _residuals(T: Array, vel: Array, pts_w: Array, uv: Array, frac: Array, cam: tuple[float, float, float, float],
               jacobian: bool) -> tuple[Array, Array, Array | None]:
    """Pixel residuals (N, 2), depths at the rows' times, and the (2N, 12) Jacobian (u rows
    then v rows) with respect to a left increment (rotation vector, translation) of ``T``
    and to ``vel``'s (rotation vector, translation). The Jacobian takes the rows' rotation
    ``R(s w)`` as the identity (|s w| <= ~0.05 rad at 200 deg/s): it shapes Gauss-Newton's
    steps, not the fixed point, which the exact residuals set."""
    fx, fy, cx, cy = cam
    pc = pts_w @ T[:3, :3].T + T[:3, 3]
    q = _rotate(frac[:, None] * vel[None, :3], pc)
    p = q + frac[:, None] * vel[None, 3:]
    z = p[:, 2]
    zs = np.where(np.abs(z) > 1e-9, z, 1e-9)
    res = np.stack([fx * p[:, 0] / zs + cx, fy * p[:, 1] / zs + cy], 1) - uv
    if not jacobian:
        return res, z, None
    x, y, iz = p[:, 0], p[:, 1], 1.0 / zs
    n = len(p)
    J = np.zeros((2 * n, 12))
    ju, jv = J[:n], J[n:]
    # d pixel / d translation (ORB-SLAM's EdgeSE3ProjectXYZOnlyPose, our sign convention)
    ju[:, 3], ju[:, 5] = fx * iz, -fx * x * iz ** 2
    jv[:, 4], jv[:, 5] = fy * iz, -fy * y * iz ** 2
    # d pixel / d rotation: d p = -[p]x d omega
    ju[:, 0], ju[:, 1], ju[:, 2] = -fx * x * y * iz ** 2, fx * (1 + x * x * iz ** 2), -fx * y * iz
    jv[:, 0], jv[:, 1], jv[:, 2] = -fy * (1 + y * y * iz ** 2), fy * x * y * iz ** 2, fy * x * iz
    # The velocity enters scaled by each row's fraction.
    J[:, 6:] = J[:, :6] * np.concatenate([frac, frac])[:, None]
    return res, z, J


def solve_rolling_shutter_pose(T_cw: Array, velocity_cw: Array, pts_w: Array, uv: Array, frac: Array,
                               inv_sigma2: Array, cam: tuple[float, float, float, float],
                               prior_sigma_rad: float = 0.05, prior_sigma_m: float = 0.02,
                               iterations: int = 3) -> RollingShutterPose:
    """Fit (T_cw, V) to raw undistorted observations ``uv`` of ``pts_w`` captured ``frac``
    frame intervals after the middle row. ``inv_sigma2``: per-observation information (the
    keypoints' pyramid levels). The prior on V is centred on ``velocity_cw`` with these
    sigmas (rotation per frame, translation per frame)."""
    n = len(pts_w)
    inliers = np.ones(n, bool)
    if n < 6:
        return RollingShutterPose(T_cw.copy(), velocity_cw.copy(), inliers)
    vel = _twist(velocity_cw)
    prior = vel.copy()
    prior_w = np.concatenate([np.full(3, 1.0 / prior_sigma_rad ** 2), np.full(3, 1.0 / prior_sigma_m ** 2)])
    delta = np.sqrt(CHI2_MONO)
    active = np.ones(n, bool)
    T_cw = T_cw.copy()
    for it in range(2 * iterations):
        res, z, J = _residuals(T_cw, vel, pts_w, uv, frac, cam, True)
        chi2 = (res ** 2).sum(1) * inv_sigma2
        if it == iterations:  # second round without the first round's outliers (ORB-SLAM's rounds)
            active = (chi2 < CHI2_MONO) & (z > 0)
            if active.sum() < 6:
                break
        norm = np.sqrt(chi2)
        w = np.where(norm <= delta, 1.0, delta / np.maximum(norm, 1e-12)) * (z > 0) * active
        wi = np.concatenate([w * inv_sigma2, w * inv_sigma2])
        Jw = J * wi[:, None]
        H = Jw.T @ J
        g = Jw.T @ np.concatenate([res[:, 0], res[:, 1]])
        H[6:, 6:] += np.diag(prior_w)
        g[6:] += prior_w * (vel - prior)
        try:  # scipy's Cholesky: numpy.linalg.solve took ~2-13 ms for 12 x 12 here (its LAPACK call)
            step = -cho_solve(cho_factor(H + 1e-9 * np.eye(12), check_finite=False), g, check_finite=False)
        except (np.linalg.LinAlgError, ValueError):
            break
        T_cw = _from_twist(step[:6]) @ T_cw
        vel = vel + step[6:]
    res, z, _ = _residuals(T_cw, vel, pts_w, uv, frac, cam, False)
    inliers = ((res ** 2).sum(1) * inv_sigma2 < CHI2_MONO) & (z > 0)
    return RollingShutterPose(T_cw, _from_twist(vel), inliers)
