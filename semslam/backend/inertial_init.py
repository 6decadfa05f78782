"""Inertial initialisation with a known scale (stereo, RGB-D): gravity's direction in the
map, the body's velocity at each frame and the IMU's biases from visually tracked poses.

ORB-SLAM3's inertial-only optimisation (Campos et al. 2021, sec. V-B) with the scale fixed:
the poses are the tracker's, held fixed; the unknowns are gravity's direction (2 DoF:
``R_wg`` applied to (0, 0, -9.81)), one velocity per frame and one bias pair, with a
Gaussian prior on the biases. Residuals are the preintegrated rotation, velocity and
position between consecutive frames (``backend/imu_preintegration.py``). As ORB-SLAM3's
``Preintegrated::GetDeltaRotation/Velocity/Position(b)``, each pair is preintegrated once at
a linearisation bias, with the deltas' Jacobians wrt the bias (by finite differences: GTSAM's
Python wrapper does not expose its own), and the solver's biases are applied to first
order. The velocity and position deltas are linear in the accelerometer bias; in the gyro
bias they curve (about |a| dt^3 / 6 per (rad/s)^2 from gravity alone): 0.01 rad/s off, a
0.2 s pair's deltas are 1e-5 m/s off at most on fast turns, a two-hundredth of their sigma.
Where the solution's bias is further than that from the linearisation bias, the pairs are
preintegrated again there and the solve repeated from it, so the answer is the exact
model's to well below its residual sigmas.

Why it needs no lively start: with the scale known, the position residuals alone pin
gravity (a camera at rest measures -g), so a slow or still start initialises; ORB-SLAM3's
monocular-inertial needs acceleration to see the scale, and its stereo-inertial refuses to
start without it too ("not enough acceleration"). What a still start cannot separate is
the accelerometer bias along gravity from gravity's magnitude (fixed) and across it from
gravity's tilt; the prior holds the bias there until motion tells them apart (the later
refinements).

A monocular map (``scaled``): its scale is one more unknown (its logarithm), started from the
closed-form linear solve of scale, gravity and velocities with the biases at their prior
(Martinelli; Mur-Artal and Tardos 2017). Only acceleration shows it, so its spread is
returned with it. Noise in the poses shrinks it a little (an errors-in-variables bias:
1-2.5 % on 9.5 s of a gently moving hand-held path with 2 mm pose noise, where ORB-SLAM3's
visual-inertial BA keeps refining it); the tracker does not use it yet (monocular-inertial
tracking is not built).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import gtsam
import numpy as np
from numpy.typing import NDArray
from scipy.optimize import least_squares
from scipy.sparse import lil_matrix
from scipy.spatial.transform import Rotation

from semslam.backend.imu_preintegration import bias_from, imu_params, interpolate_readings, preintegrate_chain
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
#: How far the solution's bias may be from the linearisation bias before the pairs are
#: preintegrated again there (gyro rad/s, accelerometer m/s^2): the first-order model's
#: error there is under a hundredth of the residual sigmas (the accelerometer's only
#: through its product with the gyro's, the deltas being linear in it).
RELINEARISE_GYRO = 0.01
RELINEARISE_ACC = 0.1
#: Repeats at most (one suffices: from the first solve's answer the second moves far less).
MAX_RELINEARISATIONS = 3
#: Finite-difference steps for the deltas' bias Jacobians (gyro rad/s, accelerometer m/s^2):
#: the curvature's error (~1e-6 relative) and the rounding's (~1e-11) both negligible.
JACOBIAN_STEPS = np.array([1e-4] * 3 + [1e-3] * 3)
#: How far (a factor, either way) a monocular scale may move from the closed-form guess.
MAX_SCALE_CHANGE = 10.0


@dataclass(frozen=True)
class InertialEstimate:
    """What the initialisation found: gravity in the map frame, the body's velocity at each
    given frame, the biases, and the RMS of the normalised residuals (~1 when consistent);
    with a monocular map, its scale (metres per map unit) and that scale's relative standard
    deviation (how well the motion showed it: ORB-SLAM3 needs acceleration for it too)."""

    gravity_w: Array
    velocities: Array  # (N, 3)
    gyro_bias: Array
    acc_bias: Array
    rms: float
    scale: float = 1.0
    scale_sigma: float = 0.0


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


def _sparsity(n: int, free_scale: bool = False) -> lil_matrix:
    """Which unknowns each residual depends on (finite differences then perturb the
    velocities of far-apart frames together: a handful of evaluations, not one per unknown).
    Columns: gravity's 2 angles, gyro bias, accelerometer bias, a velocity per frame, then
    the map's log-scale when free; rows: rotation, velocity and position residuals per pair,
    then the bias priors."""
    m = n - 1
    S = lil_matrix((9 * m + 6, 8 + 3 * n + int(free_scale)), dtype=np.int8)
    if free_scale:
        S[6 * m:9 * m, -1] = 1
    for i in range(m):
        S[3 * i:3 * i + 3, 2:5] = 1  # rotation: gyro bias only
        for rows in (slice(3 * m + 3 * i, 3 * m + 3 * i + 3), slice(6 * m + 3 * i, 6 * m + 3 * i + 3)):
            S[rows, 0:8] = 1
            S[rows, 8 + 3 * i:8 + 3 * i + 3] = 1
        S[3 * m + 3 * i:3 * m + 3 * i + 3, 8 + 3 * (i + 1):8 + 3 * (i + 2)] = 1  # velocity: v_j too
    S[9 * m:, 2:8] = np.eye(6, dtype=np.int8)
    return S


class _FirstOrderDeltas:
    """The consecutive pairs' preintegrated rotation, velocity and position at any bias, to
    first order about a linearisation bias (gyro then accelerometer, 6-vector):
    ``dR0 Exp(J_R dbg)``, ``dv0 + J_v db``, ``dp0 + J_p db`` as ORB-SLAM3's."""

    def __init__(self, params: gtsam.PreintegrationCombinedParams, samples: ImuSamples, times: Array,
                 bias: Array) -> None:
        self.params, self.samples, self.times = params, samples, times
        self.relinearise(bias)

    def relinearise(self, bias: Array) -> None:
        """Preintegrate the pairs at ``bias`` and at each component stepped by ``JACOBIAN_STEPS``."""
        self.b0 = np.asarray(bias, dtype=np.float64).copy()
        trials = [self.b0] + [self.b0 + h * e for h, e in zip(JACOBIAN_STEPS, np.eye(6))]
        chains = preintegrate_chain(self.params, [bias_from(b[:3], b[3:]) for b in trials], self.samples, self.times)
        dR = np.array([[pim.deltaRij().matrix() for pim in chain] for chain in chains])  # (7, m, 3, 3)
        dv = np.array([[pim.deltaVij() for pim in chain] for chain in chains])  # (7, m, 3)
        dp = np.array([[pim.deltaPij() for pim in chain] for chain in chains])
        self.dR0, self.dv0, self.dp0 = dR[0], dv[0], dp[0]
        m = dR.shape[1]
        step = np.transpose(dR[0], (0, 2, 1))[None] @ dR[1:4]  # dR0^T dR(b0 + h e_k), k = gyro
        self.J_R = (Rotation.from_matrix(step.reshape(-1, 3, 3)).as_rotvec().reshape(3, m, 3)
                    / JACOBIAN_STEPS[:3, None, None]).transpose(1, 2, 0)  # (m, 3, 3)
        self.J_v = ((dv[1:] - dv[0]) / JACOBIAN_STEPS[:, None, None]).transpose(1, 2, 0)  # (m, 3, 6)
        self.J_p = ((dp[1:] - dp[0]) / JACOBIAN_STEPS[:, None, None]).transpose(1, 2, 0)

    def far_from(self, bias: Array) -> bool:
        """Whether ``bias`` is beyond where the first-order model is trusted."""
        db = np.asarray(bias) - self.b0
        return bool(np.linalg.norm(db[:3]) > RELINEARISE_GYRO or np.linalg.norm(db[3:]) > RELINEARISE_ACC)

    def at(self, bias: Array) -> tuple[Array, Array, Array]:
        """Rotations (m, 3, 3), velocity and position deltas (m, 3) at ``bias``."""
        db = np.asarray(bias) - self.b0
        dR = self.dR0 @ Rotation.from_rotvec(self.J_R @ db[:3]).as_matrix()
        return dR, self.dv0 + self.J_v @ db, self.dp0 + self.J_p @ db


def _linear_guess(c: Array, lever: Array, R: Array, dts: Array, dv: Array, dp: Array) -> tuple[float, Array, Array]:
    """The scale, gravity (a free 3-vector) and velocities from the position and velocity
    residuals with the biases at their linearisation point, which are linear in them (the
    closed-form initialisation of Martinelli / Mur-Artal and Tardos): where the monocular
    solve starts."""
    m = len(dts)
    n = m + 1
    A = np.zeros((6 * m, 4 + 3 * n))
    b = np.zeros(6 * m)
    eye = np.eye(3)
    for i in range(m):
        rp, rv = slice(3 * i, 3 * i + 3), slice(3 * m + 3 * i, 3 * m + 3 * i + 3)
        vi, vj = slice(4 + 3 * i, 7 + 3 * i), slice(7 + 3 * i, 10 + 3 * i)
        # s (c_j - c_i) - v_i dt - g dt^2 / 2 = R_i dp - (lever_j - lever_i)
        A[rp, 0] = (c[i + 1] - c[i]) / POSITION_SIGMA_M
        A[rp, 1:4] = -0.5 * dts[i] ** 2 * eye / POSITION_SIGMA_M
        A[rp, vi] = -dts[i] * eye / POSITION_SIGMA_M
        b[rp] = (R[i] @ dp[i] - (lever[i + 1] - lever[i])) / POSITION_SIGMA_M
        # v_j - v_i - g dt = R_i dv
        A[rv, 1:4] = -dts[i] * eye / VELOCITY_SIGMA_MPS
        A[rv, vi] = -eye / VELOCITY_SIGMA_MPS
        A[rv, vj] = eye / VELOCITY_SIGMA_MPS
        b[rv] = R[i] @ dv[i] / VELOCITY_SIGMA_MPS
    y = np.linalg.lstsq(A, b, rcond=None)[0]
    return float(y[0]), y[1:4], y[4:].reshape(n, 3)


def initialise(times: Array, T_wb: Array, samples: ImuSamples, noise: ImuNoise,
               gyro_bias: Array | None = None, acc_bias: Array | None = None,
               scaled: Array | None = None) -> InertialEstimate:
    """Gravity, velocities and biases for the frames at ``times`` with body poses ``T_wb``
    (N >= 3, a second or more of motion or rest); ``samples`` cover the span. A known bias
    (a refinement's start) seeds the solver and centres the bias prior.

    ``scaled``: for a monocular map, the part of each body position that is in map units
    (the camera centres; the rest, the camera-to-body lever arm, is metric): the map's scale
    is estimated too, the body at ``scale * scaled + (position - scaled)``. That needs
    acceleration; ``scale_sigma`` says how well the motion showed it."""
    times = np.asarray(times, dtype=np.float64)
    n = len(times)
    if n < 3:
        raise ValueError("inertial initialisation needs at least 3 frames")
    bg0 = np.zeros(3) if gyro_bias is None else np.asarray(gyro_bias, dtype=np.float64)
    ba0 = np.zeros(3) if acc_bias is None else np.asarray(acc_bias, dtype=np.float64)
    R, p = T_wb[:, :3, :3], T_wb[:, :3, 3]
    free = scaled is not None
    c = np.asarray(scaled, dtype=np.float64) if free else p
    lever = p - c
    dts = np.diff(times)
    params = imu_params(noise, np.array([0.0, 0.0, -GRAVITY]))  # preintegration ignores gravity
    model = _FirstOrderDeltas(params, samples, times, np.concatenate([bg0, ba0]))

    if free:
        scale0, g_lin, v_guess = _linear_guess(c, lever, R, dts, model.dv0, model.dp0)
        scale0 = scale0 if scale0 > 0 else 1.0
        g_dir = g_lin / max(np.linalg.norm(g_lin), 1e-9)
    else:
        scale0, v_guess = 1.0, np.gradient(p, times, axis=0)
        g_dir = gravity_direction_guess(T_wb, samples, times)
    R_wg0 = _rotation_to(g_dir)
    down = np.array([0.0, 0.0, -GRAVITY])

    def unpack(x: Array) -> tuple[Array, Array, Array, float]:
        R_wg = R_wg0 @ so3_exp(np.array([x[0], x[1], 0.0]))
        return R_wg @ down, x[2:8], x[8:8 + 3 * n].reshape(n, 3), float(np.exp(x[-1])) if free else 1.0

    def residuals(x: Array) -> Array:
        g, bias, v, scale = unpack(x)
        dR, dv, dp = model.at(bias)
        Ri = R[:-1]
        RiT = np.transpose(Ri, (0, 2, 1))
        err = np.transpose(dR, (0, 2, 1)) @ RiT @ R[1:]
        r_rot = Rotation.from_matrix(err).as_rotvec() / ROTATION_SIGMA_RAD
        r_vel = (np.einsum("nij,nj->ni", RiT, v[1:] - v[:-1] - g * dts[:, None]) - dv) / VELOCITY_SIGMA_MPS
        rel = (scale * (c[1:] - c[:-1]) + lever[1:] - lever[:-1] - v[:-1] * dts[:, None]
               - 0.5 * g * dts[:, None] ** 2)
        r_pos = (np.einsum("nij,nj->ni", RiT, rel) - dp) / POSITION_SIGMA_M
        r_prior = np.concatenate([(bias[:3] - bg0) / GYRO_BIAS_PRIOR, (bias[3:] - ba0) / ACC_BIAS_PRIOR])
        return np.concatenate([r_rot.ravel(), r_vel.ravel(), r_pos.ravel(), r_prior])

    x0 = np.concatenate([[0.0, 0.0], bg0, ba0, v_guess.ravel(), [np.log(scale0)] if free else []])
    # Robust (soft L1 beyond one sigma): a frame posed a little off on a blurred turn must
    # not tilt gravity; the spread below is read on the residuals the fit kept.
    sparsity = _sparsity(n, free)
    # A monocular map's scale kept within MAX_SCALE_CHANGE of the linear guess either way: on
    # poses the readings do not fit, the log-scale would run off to where exp overflows.
    lower = np.full(len(x0), -np.inf)
    upper = np.full(len(x0), np.inf)
    if free:
        lower[-1], upper[-1] = x0[-1] - np.log(MAX_SCALE_CHANGE), x0[-1] + np.log(MAX_SCALE_CHANGE)
    sol = least_squares(residuals, x0, method="trf", x_scale="jac", jac_sparsity=sparsity, max_nfev=200,
                        loss="soft_l1", bounds=(lower, upper))
    for _ in range(MAX_RELINEARISATIONS):
        if not model.far_from(sol.x[2:8]):
            break
        model.relinearise(sol.x[2:8])
        sol = least_squares(residuals, sol.x, method="trf", x_scale="jac", jac_sparsity=sparsity, max_nfev=200,
                            loss="soft_l1", bounds=(lower, upper))
    g, bias, v, scale = unpack(sol.x)
    rms = float(np.sqrt(np.mean(np.minimum(sol.fun**2, ROBUST_CLIP**2))))  # ~0.3 when poses and readings agree
    return InertialEstimate(g, v, bias[:3].copy(), bias[3:].copy(), rms, scale,
                            _log_scale_sigma(sol.jac) if free else 0.0)


def _log_scale_sigma(jac: Any) -> float:
    """The log-scale's standard deviation (the last unknown) from the solution's Jacobian of
    the normalised residuals: the scale's relative spread, to first order."""
    J = jac.toarray() if hasattr(jac, "toarray") else np.asarray(jac)
    info = J.T @ J
    try:
        return float(np.sqrt(max(np.linalg.inv(info)[-1, -1], 0.0)))
    except np.linalg.LinAlgError:
        return float("inf")
