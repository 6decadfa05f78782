"""Inertial initialisation with a known scale (stereo, RGB-D): gravity's direction in the
map, the body's velocity at each frame and the IMU's biases from visually tracked poses.

ORB-SLAM3's inertial-only optimisation (Campos et al. 2021, sec. V-B) with the scale fixed:
the poses are the tracker's, held fixed; the unknowns are gravity's direction (2 DoF:
``R_wg`` applied to (0, 0, -9.81)), one velocity per frame and one bias pair, with a
Gaussian prior on the biases. Residuals are the preintegrated rotation, velocity and
position between consecutive frames (``backend/imu_preintegration.py``), each pair
preintegrated again at every bias the solver tries, so there is no first-order bias
correction to trust far from its linearisation point.

Why it needs no lively start: with the scale known, the position residuals alone pin
gravity (a camera at rest measures -g), so a slow or still start initialises; ORB-SLAM3's
monocular-inertial needs acceleration to see the scale, and its stereo-inertial refuses to
start without it too ("not enough acceleration"). What a still start cannot separate is
the accelerometer bias along gravity from gravity's magnitude (fixed) and across it from
gravity's tilt; the prior holds the bias there until motion tells them apart (the later
refinements).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import least_squares
from scipy.sparse import lil_matrix
from scipy.spatial.transform import Rotation

from semslam.backend.imu_preintegration import bias_from, imu_params, interpolate_readings, preintegrate
from semslam.core.imu import GRAVITY, ImuNoise, ImuSamples
from semslam.geometry.se3 import so3_exp

Array = NDArray[np.float64]

#: Residual scales: a tracked pose is good to a few millimetres and a tenth of a degree;
#: velocities are free, so their residual is the IMU's own (kept as tight as positions).
POSITION_SIGMA_M = 0.005
ROTATION_SIGMA_RAD = np.deg2rad(0.2)
VELOCITY_SIGMA_MPS = 0.002
#: Normalised residuals beyond this count as this much in the fit's spread (an outlier pair).
ROBUST_CLIP = 3.0
#: Bias priors (ORB-SLAM3 puts a prior on both in its inertial-only optimisation).
GYRO_BIAS_PRIOR = 0.05  # rad/s
ACC_BIAS_PRIOR = 0.2  # m/s^2


@dataclass(frozen=True)
class InertialEstimate:
    """What the initialisation found: gravity in the map frame, the body's velocity at each
    given frame, the biases, and the RMS of the normalised residuals (~1 when consistent)."""

    gravity_w: Array
    velocities: Array  # (N, 3)
    gyro_bias: Array
    acc_bias: Array
    rms: float


def gravity_direction_guess(T_wb: Array, samples: ImuSamples, times: Array) -> Array:
    """Gravity's direction from the mean specific force seen in the world (a slowly moving
    IMU measures -g): the starting point of the optimisation."""
    _, acc = interpolate_readings(samples, times)
    f_w = np.einsum("nij,nj->ni", T_wb[:, :3, :3], acc).mean(axis=0)
    return -f_w / max(np.linalg.norm(f_w), 1e-9)


def _rotation_to(direction: Array) -> Array:
    """A rotation taking (0, 0, -1) to ``direction``."""
    down = np.array([0.0, 0.0, -1.0])
    axis = np.cross(down, direction)
    s, c = np.linalg.norm(axis), float(down @ direction)
    if s < 1e-12:
        return np.eye(3) if c > 0 else np.diag([1.0, -1.0, -1.0])
    return so3_exp(axis / s * np.arctan2(s, c))


def _sparsity(n: int) -> lil_matrix:
    """Which unknowns each residual depends on (finite differences then perturb the
    velocities of far-apart frames together: a handful of evaluations, not one per unknown).
    Columns: gravity's 2 angles, gyro bias, accelerometer bias, then a velocity per frame;
    rows: rotation, velocity and position residuals per pair, then the bias priors."""
    m = n - 1
    S = lil_matrix((9 * m + 6, 8 + 3 * n), dtype=np.int8)
    for i in range(m):
        S[3 * i:3 * i + 3, 2:5] = 1  # rotation: gyro bias only
        for rows in (slice(3 * m + 3 * i, 3 * m + 3 * i + 3), slice(6 * m + 3 * i, 6 * m + 3 * i + 3)):
            S[rows, 0:8] = 1
            S[rows, 8 + 3 * i:8 + 3 * i + 3] = 1
        S[3 * m + 3 * i:3 * m + 3 * i + 3, 8 + 3 * (i + 1):8 + 3 * (i + 2)] = 1  # velocity: v_j too
    S[9 * m:, 2:8] = np.eye(6, dtype=np.int8)
    return S


def initialise(times: Array, T_wb: Array, samples: ImuSamples, noise: ImuNoise,
               gyro_bias: Array | None = None, acc_bias: Array | None = None) -> InertialEstimate:
    """Gravity, velocities and biases for the frames at ``times`` with body poses ``T_wb``
    (N >= 3, a second or more of motion or rest); ``samples`` cover the span. A known bias
    (a refinement's start) seeds the solver and centres the bias prior."""
    times = np.asarray(times, dtype=np.float64)
    n = len(times)
    if n < 3:
        raise ValueError("inertial initialisation needs at least 3 frames")
    bg0 = np.zeros(3) if gyro_bias is None else np.asarray(gyro_bias, dtype=np.float64)
    ba0 = np.zeros(3) if acc_bias is None else np.asarray(acc_bias, dtype=np.float64)
    R, p = T_wb[:, :3, :3], T_wb[:, :3, 3]
    dts = np.diff(times)
    windows = [samples.bracketing(times[i], times[i + 1]) for i in range(n - 1)]
    params = imu_params(noise, np.array([0.0, 0.0, -GRAVITY]))  # preintegration ignores gravity
    cache: dict[bytes, tuple[Array, Array, Array]] = {}

    def deltas(bias: Array) -> tuple[Array, Array, Array]:
        key = bias.tobytes()
        if key not in cache:
            if len(cache) > 64:
                cache.clear()
            b = bias_from(bias[:3], bias[3:])
            dR, dv, dp = [], [], []
            for i, w in enumerate(windows):
                pim = preintegrate(params, b, w, times[i], times[i + 1])
                dR.append(np.asarray(pim.deltaRij().matrix()))
                dv.append(np.asarray(pim.deltaVij()))
                dp.append(np.asarray(pim.deltaPij()))
            cache[key] = (np.array(dR), np.array(dv), np.array(dp))
        return cache[key]

    g_dir = gravity_direction_guess(T_wb, samples, times)
    R_wg0 = _rotation_to(g_dir)
    down = np.array([0.0, 0.0, -GRAVITY])

    def unpack(x: Array) -> tuple[Array, Array, Array]:
        R_wg = R_wg0 @ so3_exp(np.array([x[0], x[1], 0.0]))
        return R_wg @ down, x[2:8], x[8:].reshape(n, 3)

    def residuals(x: Array) -> Array:
        g, bias, v = unpack(x)
        dR, dv, dp = deltas(bias)
        Ri = R[:-1]
        RiT = np.transpose(Ri, (0, 2, 1))
        err = np.transpose(dR, (0, 2, 1)) @ RiT @ R[1:]
        r_rot = Rotation.from_matrix(err).as_rotvec() / ROTATION_SIGMA_RAD
        r_vel = (np.einsum("nij,nj->ni", RiT, v[1:] - v[:-1] - g * dts[:, None]) - dv) / VELOCITY_SIGMA_MPS
        rel = p[1:] - p[:-1] - v[:-1] * dts[:, None] - 0.5 * g * dts[:, None] ** 2
        r_pos = (np.einsum("nij,nj->ni", RiT, rel) - dp) / POSITION_SIGMA_M
        r_prior = np.concatenate([(bias[:3] - bg0) / GYRO_BIAS_PRIOR, (bias[3:] - ba0) / ACC_BIAS_PRIOR])
        return np.concatenate([r_rot.ravel(), r_vel.ravel(), r_pos.ravel(), r_prior])

    v_guess = np.gradient(p, times, axis=0)
    x0 = np.concatenate([[0.0, 0.0], bg0, ba0, v_guess.ravel()])
    # Robust (soft L1 beyond one sigma): a frame posed a little off on a blurred turn must
    # not tilt gravity; the spread below is read on the residuals the fit kept.
    sol = least_squares(residuals, x0, method="trf", x_scale="jac", jac_sparsity=_sparsity(n), max_nfev=200,
                        loss="soft_l1")
    g, bias, v = unpack(sol.x)
    rms = float(np.sqrt(np.mean(np.minimum(sol.fun**2, ROBUST_CLIP**2))))  # ~0.3 when poses and readings agree
    return InertialEstimate(g, v, bias[:3].copy(), bias[3:].copy(), rms)
